"""`feeder teach`: a scenario learnt from labelled images, scored on held-out ones.

Real photos (tests/data: a museum photo of coins of three sizes under a front light, and
oysters with coins under a front light and on a light box, REAL_SETS) and frames the simulated cell renders with its truth as the labels (washers and
slugs told apart by a hole, front-lit concave brackets, hex nuts in two poses). Each is
taught from half its images and scored on the other half, against the plain OpenCV
pipeline (Otsu, contours, nearest class by area) on the same images."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario
from feeder_bt.core.geometry import outer, place_outline, pose_outline
from feeder_bt.core.images import BadInput
from feeder_bt.tuning.evaluate import held_out
from feeder_bt.tuning.teach import Measured, learn_classes, learn_outline

ROOT = Path(__file__).resolve().parents[2]
COINS = ROOT / "tests/data/greek_coins"
ROWS = [str(p) for p in sorted(COINS.glob("row_*.png"))]


def teach(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["teach", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def f1s(out: str) -> tuple[float, float]:
    """(taught, plain baseline) F1 from `feeder teach --validate`'s last lines."""
    taught = float(re.search(r"taught recipe: F1 ([\d.]+)", out).group(1))
    plain = float(re.search(r"nearest class by area\) on the same images: F1 ([\d.]+)",
                            out).group(1))
    return taught, plain


# ---------------------------------------------------------------------------- real photos


#: Real photo sets (tests/data/README.md: source, licence, how labelled): folder, images.
#: Each is taught from half its images and scored on the other half, both ways round.
REAL_SETS = {
    "greek_coins": "row_*.png",
    "oysters": "oysters_*.jpg",
    "oysters_backlit": "backlit_*.jpg",
}
#: Halves that do not pass yet (F1 0.95 and above the plain pipeline), with their figures
#: (taught / plain).
SHORT: dict[tuple[str, bool], str] = {}


def _split(tmp_path: Path, folder: Path, pattern: str, other_half: bool) -> list[str]:
    """The set's images, as they are or (``other_half``) copied under names that put the
    other half where ``--validate 0.5`` holds images out (every second one by name)."""
    import shutil
    images = sorted(folder.glob(pattern))
    if not other_half:
        return [str(p) for p in images]
    doc = json.loads((folder / "labels.json").read_text())
    # swap each pair: the 1st and 2nd image trade places, the 3rd and 4th, ...
    names = {}
    for i, p in enumerate(images):
        j = i ^ 1 if (i ^ 1) < len(images) else i
        names[p.name] = f"{j:03d}_{p.name}"
        shutil.copy(p, tmp_path / names[p.name])
    for im in doc["images"]:
        im["file_name"] = names.get(Path(im["file_name"]).name, im["file_name"])
    (tmp_path / "labels.json").write_text(json.dumps(doc))
    return sorted(str(tmp_path / n) for n in names.values())


@pytest.mark.parametrize(("name", "other_half"), [
    pytest.param(n, o, id=f"{n}-{'other' if o else 'first'}_half",
                 marks=[pytest.mark.xfail(strict=True, reason=SHORT[n, o])]
                 if (n, o) in SHORT else [])
    for n in sorted(REAL_SETS) for o in (False, True)])
def test_real_photos_taught_from_half_find_the_other_half(tmp_path, capsys, name, other_half):
    folder = ROOT / "tests/data" / name
    images = _split(tmp_path, folder, REAL_SETS[name], other_half)
    labels = tmp_path / "labels.json" if other_half else folder / "labels.json"
    code, text, err = teach(capsys, *images, "--labels", str(labels), "--cell",
                            str(folder / "cell.yaml"), "--out", str(tmp_path / "t.yaml"),
                            "--validate", "0.5")
    assert code == 0, err
    held = re.search(r"held out (\d+) of (\d+) image", text)
    assert 2 * int(held.group(1)) >= int(held.group(2)) >= 2
    taught, plain = f1s(text)
    assert taught > plain or taught == 1.0, text     # nothing is above finding every part
    assert taught >= 0.95, text


def test_coins_taught_from_half_the_rows_find_the_other_half(tmp_path, capsys):
    """What the taught file is: an ordinary scenario that feeder check takes and feeder
    locate runs (the F1 of each half: the test above)."""
    out = tmp_path / "coins.yaml"
    code, text, err = teach(capsys, *ROWS, "--labels", str(COINS / "labels.json"),
                            "--cell", str(COINS / "cell.yaml"), "--out", str(out),
                            "--validate", "0.5")
    assert code == 0, err
    assert "held out 2 of 4 image(s): row_2.png, row_4.png" in text
    assert main(["check", str(out)]) == 0
    capsys.readouterr()
    assert main(["locate", str(out), ROWS[1], "--json"]) == 0
    found = json.loads(capsys.readouterr().out)
    kinds = sorted(p["part"] for p in found[0]["parts"])
    assert kinds == ["medium_coin", "medium_coin", "small_coin", "small_coin", "small_coin",
                     "small_coin"]
    assert "# Taught by `feeder teach` from 2 image(s)" in out.read_text()
    sc, _ = load_scenario(out)
    small = sc.parts["small_coin"]
    assert not small.shape.holes_mm and small.symmetry == 360     # a disc


def test_coins_taught_from_every_row_pass_feeder_check(tmp_path, capsys):
    out = tmp_path / "all.yaml"
    code, text, err = teach(capsys, *ROWS, "--labels", str(COINS / "labels.json"),
                            "--cell", str(COINS / "cell.yaml"), "--out", str(out))
    assert code == 0, err
    assert "held out" not in text
    sc, _ = load_scenario(out)
    assert sorted(sc.parts) == ["large_coin", "medium_coin", "small_coin"]
    areas = {c.part: c.ranges["area_mm2"] for c in sc.vision.classes}
    # the sizes follow each other without a gap or an overlap: the nearer class wins
    assert areas["small_coin"][1] <= areas["medium_coin"][0]
    assert areas["medium_coin"][1] <= areas["large_coin"][0]


def test_euro_coins_that_no_feature_tells_apart_are_an_error_naming_both(tmp_path, capsys):
    """Eight denominations, some 1 mm apart, shiny ones as bright as the paper: their
    measured areas overlap, and teach says so rather than write ranges that mix them."""
    euro = ROOT / "tests/data/euro_coins"
    code, _, err = teach(capsys, *sorted(str(p) for p in euro.glob("euro_*.jpg")),
                         "--labels", str(euro / "labels.json"), "--cell",
                         str(euro / "cell.yaml"), "--out", str(tmp_path / "euro.yaml"),
                         "--validate", "0.5")
    assert code == 2 and err.count("\n") == 1
    pair = re.search(r"classes (\w+)/flat and (\w+)/flat overlap in every feature", err)
    assert pair and {pair[1], pair[2]} <= {"cent_1", "cent_2", "cent_5", "cent_10",
                                           "cent_20", "cent_50", "euro_1", "euro_2"}
    assert not (tmp_path / "euro.yaml").exists()


# ---------------------------------------------------------------------------- rendered frames


def _truth_to_coco(frames: Path, scenario: str) -> Path:
    """COCO labels from the simulator's truth: each whole part's outline placed at its pose,
    its extent in pixels (the simulated camera: x along v, y along u, ~1 mm a pixel)."""
    sc, cell = load_scenario(scenario)
    s = cell.camera.calibration.mm_per_px
    cats: dict[str, int] = {}
    images, anns = [], []
    for i, f in enumerate(sorted(frames.glob("frame_*.json"))):
        truth = json.loads(f.read_text())
        images.append({"id": i, "file_name": f.with_suffix(".png").name})
        for p in truth["parts"]:
            if not p.get("whole", True):
                continue
            name = f"{p['type']}/{p['pose']}"
            cats.setdefault(name, len(cats) + 1)
            ring = place_outline(outer(pose_outline(sc.parts[p["type"]], p["pose"])),
                                 0.0, 0.0, p["angle_deg"])
            du, dv = ring[:, 1] / s, ring[:, 0] / s
            x0, x1 = p["u_px"] + du.min() - 2, p["u_px"] + du.max() + 2
            y0, y1 = p["v_px"] + dv.min() - 2, p["v_px"] + dv.max() + 2
            anns.append({"id": len(anns) + 1, "image_id": i, "category_id": cats[name],
                         "bbox": [x0, y0, x1 - x0, y1 - y0]})
    doc = {"images": images, "annotations": anns,
           "categories": [{"id": v, "name": k} for k, v in cats.items()]}
    path = frames / "labels.json"
    path.write_text(json.dumps(doc))
    return path


# Teaching from rendered frames searches every threshold with every opening and closing
# (480 candidates) on ten frames: about 30 s a test. They run with the soak (CI runs it),
# keeping the README's test command within its five minutes on two cores; the real photo
# sets above, quicker, stay in it.
@pytest.mark.soak
@pytest.mark.parametrize("scenario, frames, seed, cell", [
    ("scenarios/washers.yaml", 10, 3, "cells/sim.yaml"),
    ("scenarios/brackets_frontlit.yaml", 10, 1, "cells/sim_frontlit.yaml"),
    ("scenarios/hex_nuts.yaml", 10, 1, "cells/sim.yaml"),
])
def test_rendered_parts_taught_from_half_the_frames(tmp_path, capsys, scenario, frames, seed,
                                                     cell):
    d = tmp_path / "frames"
    assert main(["render", str(ROOT / scenario), "--out", str(d), "--frames", str(frames),
                 "--seed", str(seed), "--truth"]) == 0
    labels = _truth_to_coco(d, str(ROOT / scenario))
    out = tmp_path / "taught.yaml"
    capsys.readouterr()
    code, text, err = teach(capsys, *sorted(str(p) for p in d.glob("frame_*.png")),
                            "--labels", str(labels), "--cell", str(ROOT / cell),
                            "--out", str(out), "--validate", "0.5")
    assert code == 0, err
    taught, plain = f1s(text)
    # drawn parts on an even belt: the plain pipeline does well too, never better
    assert taught >= 0.95 and taught >= plain, text
    assert main(["check", str(out)]) == 0


@pytest.mark.soak                      # about 35 s: as the rendered frames above
def test_washer_and_slug_are_told_apart_by_the_hole(tmp_path, capsys):
    d = tmp_path / "frames"
    assert main(["render", str(ROOT / "scenarios/washers.yaml"), "--out", str(d),
                 "--frames", "8", "--seed", "3", "--truth"]) == 0
    labels = _truth_to_coco(d, str(ROOT / "scenarios/washers.yaml"))
    out = tmp_path / "w.yaml"
    code, _, err = teach(capsys, *sorted(str(p) for p in d.glob("frame_*.png")),
                         "--labels", str(labels), "--cell", str(ROOT / "cells/sim.yaml"),
                         "--out", str(out))
    assert code == 0, err
    sc, _ = load_scenario(out)
    holes = {c.part: c.ranges.get("holes") for c in sc.vision.classes}
    assert holes == {"washer": (1.0, 1.0), "slug": (0.0, 0.0)}
    assert "slug/flat and washer/flat are told apart by holes" in out.read_text()
    washer = sc.parts["washer"]
    assert len(washer.shape.holes_mm) == 1 and not sc.parts["slug"].shape.holes_mm
    # the pick is on the ring, not over the hole the centroid lies in
    g = washer.pick.grips[0].offset_mm
    assert 4.5 < float(np.hypot(*g)) < 12.0


def test_part_folders_teach_without_labels(tmp_path, capsys):
    """--part NAME=DIR: every blob in the folder's images is that part."""
    d = tmp_path / "frames"
    assert main(["render", str(ROOT / "scenarios/lenses.yaml"), "--out", str(d),
                 "--frames", "4", "--seed", "1"]) == 0
    (d / "golden.png").unlink()
    out = tmp_path / "lens.yaml"
    code, text, err = teach(capsys, "--part", f"lens={d}", "--cell",
                            str(ROOT / "cells/sim.yaml"), "--out", str(out))
    assert code == 0, err
    sc, _ = load_scenario(out)
    assert list(sc.parts) == ["lens"] and sc.parts["lens"].symmetry == 360
    assert main(["locate", str(out), str(sorted(d.glob("frame_*.png"))[0])]) == 0


def _textured_frames(d: Path, n: int = 8) -> Path:
    """Frames of dark discs of two sizes on a busy printed background that stays put (a
    patterned belt), the discs elsewhere in each frame; and their COCO labels."""
    import cv2
    rng = np.random.default_rng(7)
    h, w = 240, 320
    noise = cv2.GaussianBlur(rng.uniform(0, 255, (h, w)).astype(np.float32), (0, 0), 3)
    belt = cv2.normalize(noise, None, 45, 235, cv2.NORM_MINMAX).astype(np.uint8)
    d.mkdir()
    images, anns = [], []
    for i in range(n):
        img = belt.copy()
        placed: list[tuple[int, int, int]] = []
        while len(placed) < 6:
            r = int(rng.choice([11, 17]))
            x, y = int(rng.integers(r + 4, w - r - 4)), int(rng.integers(r + 4, h - r - 4))
            if all((x - a) ** 2 + (y - b) ** 2 > (r + c + 6) ** 2 for a, b, c in placed):
                placed.append((x, y, r))
        for x, y, r in placed:
            cv2.circle(img, (x, y), r, 0, -1, lineType=cv2.LINE_AA)
            anns.append({"id": len(anns) + 1, "image_id": i, "category_id": 1 if r < 14 else 2,
                         "bbox": [x - r - 2, y - r - 2, 2 * r + 4, 2 * r + 4]})
        cv2.imwrite(str(d / f"f{i}.png"), img)
        images.append({"id": i, "file_name": f"f{i}.png"})
    (d / "labels.json").write_text(json.dumps({
        "images": images, "annotations": anns,
        "categories": [{"id": 1, "name": "small"}, {"id": 2, "name": "large"}]}))
    return d


def test_a_patterned_belt_is_taken_out_by_the_median_of_the_frames(tmp_path, capsys):
    d = _textured_frames(tmp_path / "frames")
    out = tmp_path / "discs.yaml"
    code, text, err = teach(capsys, *sorted(str(p) for p in d.glob("f*.png")), "--labels",
                            str(d / "labels.json"), "--cell", str(COINS / "cell.yaml"),
                            "--out", str(out), "--validate", "0.5")
    assert code == 0, err
    assert "against the median of the frames" in text.splitlines()[0]
    golden = tmp_path / "discs_golden.png"
    assert f"wrote {golden}" in text and "golden_image: true" in out.read_text()
    assert f1s(text)[0] >= 0.95
    capsys.readouterr()
    assert main(["locate", str(out), str(d / "f1.png"), "--golden", str(golden), "--json"]) == 0
    found = json.loads(capsys.readouterr().out)[0]
    assert len(found["parts"]) == 6 and not found["rejected"]


# ---------------------------------------------------------------------------- the learning


def _disc(r: float, hole: float = 0.0, n: int = 90, dx: float = 0.0) -> Measured:
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.c_[r * np.cos(a), r * np.sin(a)]
    holes = [np.c_[hole * np.cos(a) + dx, hole * np.sin(a)]] if hole else []
    area = np.pi * (r * r - hole * hole)
    return Measured({"area_mm2": area}, ring, holes)


def test_a_washer_outline_is_a_ring_turned_any_way_and_picked_on_the_ring():
    o = learn_outline([_disc(12.0, 5.0) for _ in range(3)])
    assert len(o.holes_mm) == 1 and o.symmetry == 360 and o.mirror_symmetric
    r = float(np.hypot(*np.array(o.points_mm).T).mean())
    assert abs(r - 12.0) < 0.4
    assert all(5.0 < np.hypot(x, y) < 12.0 for x, y in o.grips_mm)
    assert len(o.grips_mm) == 4


def test_an_off_centre_hole_has_no_rotational_symmetry():
    o = learn_outline([_disc(12.0, 3.0, dx=5.0) for _ in range(3)])
    assert o.symmetry == 1 and o.mirror_symmetric


def _class(values: dict[str, list[float]]) -> list[Measured]:
    n = len(next(iter(values.values())))
    return [Measured({k: v[i] for k, v in values.items()}, np.zeros((3, 2)), [])
            for i in range(n)]


FLAT = {"holes": [0, 0, 0], "hole_area_mm2": [0, 0, 0], "perimeter_mm": [80, 80, 80],
        "hu1": [0.16, 0.16, 0.16], "hu2": [0, 0, 0], "aspect": [1.0, 1.02, 1.01],
        "rectangularity": [0.78, 0.79, 0.78], "solidity": [0.98, 0.99, 0.985],
        "circularity": [0.95, 0.97, 0.96]}


def test_classes_alike_in_every_feature_are_an_error_naming_both():
    a = _class({"area_mm2": [450, 460, 455], **FLAT})
    b = _class({"area_mm2": [452, 458, 456], **FLAT})
    with pytest.raises(BadInput, match=r"classes a/flat and b/flat overlap in every feature"):
        learn_classes({("a", "flat"): a, ("b", "flat"): b})


def test_a_feature_is_added_to_separate_classes_of_one_size():
    a = _class({"area_mm2": [450, 460, 455], **FLAT})
    b = _class({"area_mm2": [452, 458, 456], **{**FLAT, "aspect": [1.6, 1.65, 1.7]}})
    ranges, separated = learn_classes({("a", "flat"): a, ("b", "flat"): b})
    assert separated == [(("a", "flat"), ("b", "flat"), "aspect")]
    assert ranges[("a", "flat")]["aspect"][1] <= ranges[("b", "flat")]["aspect"][0]


def test_a_grey_feature_separates_classes_alike_in_every_outline_feature():
    """Brass and steel washers of one size under a front light: the outline cannot tell
    them apart, the grey under the blob can."""
    a = _class({"area_mm2": [450, 460, 455], **FLAT, "grey_mean": [150, 158, 154],
                "grey_std": [20, 22, 21]})
    b = _class({"area_mm2": [452, 458, 456], **FLAT, "grey_mean": [80, 86, 83],
                "grey_std": [20, 21, 22]})
    ranges, separated = learn_classes({("a", "flat"): a, ("b", "flat"): b})
    assert separated == [(("a", "flat"), ("b", "flat"), "grey_mean")]
    assert ranges[("b", "flat")]["grey_mean"][1] <= ranges[("a", "flat")]["grey_mean"][0]


def test_an_outline_feature_is_preferred_to_the_grey():
    a = _class({"area_mm2": [450, 460, 455], **FLAT, "grey_mean": [150, 158, 154],
                "grey_std": [20, 22, 21]})
    b = _class({"area_mm2": [452, 458, 456], **{**FLAT, "aspect": [1.6, 1.65, 1.7]},
                "grey_mean": [80, 86, 83], "grey_std": [20, 21, 22]})
    _, separated = learn_classes({("a", "flat"): a, ("b", "flat"): b})
    assert separated == [(("a", "flat"), ("b", "flat"), "aspect")]


def test_held_out_images_are_spread_evenly_and_always_the_same():
    assert held_out(4, 0.5) == [1, 3]
    assert held_out(10, 0.3) == [3, 6, 9]


# ---------------------------------------------------------------------------- bad input


def _labels(tmp_path: Path, doc) -> str:
    p = tmp_path / "labels.json"
    p.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    return str(p)


GOOD = {"images": [{"id": 1, "file_name": "row_1.png"}],
        "annotations": [{"id": 1, "image_id": 1, "category_id": 1, "bbox": [20, 20, 40, 40]}],
        "categories": [{"id": 1, "name": "coin"}]}


@pytest.mark.parametrize("doc, images, what", [
    ("{not json", [ROWS[0]], "not JSON"),
    ({"images": []}, [ROWS[0]], "no annotations[] list"),
    ({**GOOD, "annotations": [{**GOOD["annotations"][0], "category_id": 7}]}, [ROWS[0]],
     "annotations[0]: unknown category_id 7"),
    ({**GOOD, "annotations": [{**GOOD["annotations"][0], "bbox": [1, 2]}]}, [ROWS[0]],
     "annotations[0]: bbox must be [x, y, width, height]"),
    (GOOD, [ROWS[1]], "no image named row_2.png in images[]"),
    ({**GOOD, "categories": [{"id": 1, "name": "coin/flat side"}]}, [ROWS[0]],
     "categories[0]: category 'coin/flat side'"),
    (GOOD, ["missing.png"], "no image named missing.png"),
])
def test_bad_labels_are_one_line_naming_the_file(tmp_path, capsys, doc, images, what):
    labels = _labels(tmp_path, doc)
    code, _, err = teach(capsys, *images, "--labels", labels, "--cell",
                         str(COINS / "cell.yaml"), "--out", str(tmp_path / "x.yaml"))
    assert code == 2
    assert err.count("\n") == 1 and what in err and "Traceback" not in err
    assert labels in err or "missing.png" in err


def test_label_studio_names_with_a_hash_prefix_match_the_image(tmp_path):
    from feeder_bt.tuning.labels import load_coco
    doc = {**GOOD, "images": [{"id": 1, "file_name": "images/5f2a9c1e-row_1.png"}]}
    (s,) = load_coco(_labels(tmp_path, doc), [ROWS[0]])
    assert s.name == "row_1.png" and [b.part for b in s.boxes] == ["coin"]


def test_a_missing_image_is_one_line_naming_it(tmp_path, capsys):
    doc = {**GOOD, "images": [{"id": 1, "file_name": "gone.png"}]}
    labels = _labels(tmp_path, doc)
    code, _, err = teach(capsys, str(tmp_path / "gone.png"), "--labels", labels, "--cell",
                         str(COINS / "cell.yaml"), "--out", str(tmp_path / "x.yaml"))
    assert code == 2 and err.count("\n") == 1 and "gone.png: image not found" in err


@pytest.mark.parametrize("args, what", [
    ([ROWS[0]], "images given without --labels"),
    (["--labels", str(COINS / "labels.json")], "give the images it labels too"),
    ([], "nothing to learn from"),
    (["--part", "coin"], "expected NAME=DIR"),
    (["--part", "coin=/nowhere"], "/nowhere: --part folder not found"),
])
def test_bad_arguments_are_one_line(tmp_path, capsys, args, what):
    code, _, err = teach(capsys, *args, "--cell", str(COINS / "cell.yaml"),
                         "--out", str(tmp_path / "x.yaml"))
    assert code == 2 and err.count("\n") == 1 and what in err


def test_validate_takes_a_fraction(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:       # a usage mistake: argparse's exit, one line
        main(["teach", *ROWS, "--labels", str(COINS / "labels.json"), "--cell",
              str(COINS / "cell.yaml"), "--out", str(tmp_path / "x.yaml"), "--validate", "2"])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1
    assert "expected a fraction between 0 and 1" in err


def test_the_largest_class_takes_a_larger_part_but_not_two_touching():
    """The oysters of the light-box photo: eleven taught shells of 3663–4458 mm², held-out
    ones of 4982 and 5136 (the margin alone stopped at 4780). The area's top reaches
    halfway to two of the class touching, so those are oysters and a clump of the two
    smallest is not."""
    areas = [3663, 3870, 3909, 3972, 4136, 4175, 4206, 4349, 4355, 4377, 4458]
    grey = {"grey_mean": [60, 62, 61], "grey_std": [9, 10, 11]}
    flat = {k: [v[i % 3] for i in range(len(areas))] for k, v in {**FLAT, **grey}.items()}
    coin = _class({"area_mm2": [491], **{k: v[:1] for k, v in {**FLAT, **grey}.items()}})
    ranges, _ = learn_classes({("oyster", "flat"): _class({"area_mm2": areas, **flat}),
                               ("coin", "flat"): coin})
    lo, hi = ranges[("oyster", "flat")]["area_mm2"]
    assert hi >= 5136 and hi < 3663 + 3870 and lo <= 3663
    # the coin's top reaches halfway to two coins, nearer than the oysters
    c_lo, c_hi = ranges[("coin", "flat")]["area_mm2"]
    assert c_lo <= 491 < c_hi < 2 * 491


def test_a_class_spread_past_twice_its_smallest_keeps_every_sample_in_its_area_range():
    """Halfway to two touching would fall inside such a class: its own large samples
    would be rejected. It keeps its margin instead."""
    areas = [100, 120, 150, 180, 220, 250]
    grey = {"grey_mean": [60, 62, 61], "grey_std": [9, 10, 11]}
    feats = {k: [v[i % 3] for i in range(len(areas))] for k, v in {**FLAT, **grey}.items()}
    ranges, _ = learn_classes({("pebble", "flat"): _class({"area_mm2": areas, **feats})})
    lo, hi = ranges[("pebble", "flat")]["area_mm2"]
    assert lo <= 100 and hi >= 250
