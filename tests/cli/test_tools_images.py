"""`feeder check --images`, `feeder locate`'s "why no part" and `feeder recipe suggest
--clusters` on rendered frames of the washer and front-lit bracket scenarios."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario

ROOT = Path(__file__).resolve().parents[2]
WASHERS = str(ROOT / "scenarios/washers.yaml")
BRACKETS = str(ROOT / "scenarios/brackets_frontlit.yaml")


@pytest.fixture(scope="module")
def washer_frames(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("washers")
    assert main(["render", WASHERS, "--out", str(out), "--frames", "14", "--seed", "3",
                 "--truth"]) == 0
    return out


@pytest.fixture(scope="module")
def bracket_frames(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("brackets")
    assert main(["render", BRACKETS, "--out", str(out), "--frames", "4", "--seed", "1",
                 "--truth"]) == 0
    return out


def _dark_recipe(tmp_path: Path) -> str:
    text = Path(BRACKETS).read_text().replace("foreground: light", "foreground: dark")
    text = text.replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    p = tmp_path / "dark.yaml"
    p.write_text(text)
    return str(p)


def test_check_images_reports_the_finds(washer_frames, capsys):
    capsys.readouterr()
    assert main(["check", WASHERS, "--images", str(washer_frames)]) == 0
    out = capsys.readouterr().out
    assert "recipe on 14 image(s)" in out and "(golden image golden.png)" in out
    counts = dict(item.rsplit(" ", 1) for item in
                  out.split("parts per class: ")[1].splitlines()[0].split(", "))
    truth = [json.loads(p.read_text()) for p in sorted(washer_frames.glob("frame_*.json"))]
    assert int(counts["washer/flat"]) > 20 and int(counts["slug/flat"]) > 10
    rows = [r for t in truth for r in (t["parts"] if isinstance(t, dict) else t)]
    # washers wholly in view are marked so in the truth (their hole does not confuse it)
    assert sum(r["whole"] for r in rows if r["type"] == "washer") > 20


def test_check_images_with_the_wrong_foreground_fails_and_says_why(bracket_frames, tmp_path,
                                                                   capsys):
    capsys.readouterr()
    assert main(["check", _dark_recipe(tmp_path), "--images", str(bracket_frames)]) == 1
    out = capsys.readouterr().out
    assert "NOTHING LOCATED in 4 image(s)" in out
    assert "set vision.foreground: light" in out


def test_check_images_needs_a_folder_of_images(tmp_path, capsys):
    assert main(["check", WASHERS, "--images", str(tmp_path / "nope")]) == 2
    assert "--images needs a folder" in capsys.readouterr().err


def test_locate_finds_light_parts_and_the_dark_recipe_says_why(bracket_frames, tmp_path,
                                                              capsys):
    frames = sorted(map(str, bracket_frames.glob("frame_*.png")))
    golden = str(bracket_frames / "golden.png")
    capsys.readouterr()
    assert main(["locate", BRACKETS, *frames, "--golden", golden, "--json"]) == 0
    light = json.loads(capsys.readouterr().out)
    truth = [json.loads(Path(f).with_suffix(".json").read_text()) for f in frames]
    found = sum(len(r["parts"]) for r in light)
    assert found >= 10
    for res, t in zip(light, truth, strict=True):
        rows = t["parts"] if isinstance(t, dict) else t
        for d in res["parts"]:
            assert min(abs(d["x_mm"] - r["x_mm"]) + abs(d["y_mm"] - r["y_mm"])
                       for r in rows) < 2.0
    assert main(["locate", _dark_recipe(tmp_path), *frames, "--golden", golden]) == 0
    out = capsys.readouterr().out
    assert "0 part(s)" in out and "with foreground: light the same recipe finds" in out


def test_suggest_clusters_proposes_washer_and_slug(washer_frames, capsys, tmp_path):
    frames = sorted(map(str, washer_frames.glob("frame_*.png")))
    capsys.readouterr()
    assert main(["recipe", "suggest", WASHERS, "--clusters", "--good", *frames, "--golden",
                 str(washer_frames / "golden.png")]) == 0
    out = capsys.readouterr().out
    classes = [line for line in out.splitlines() if line.startswith("- {")]
    assert len(classes) == 2
    washer = next(c for c in classes if "part: washer" in c)
    slug = next(c for c in classes if "part: slug" in c)
    assert "holes: [1, 1]" in washer and "holes: [0, 0]" in slug
    # the proposed classes, pasted into the scenario, tell the two apart on the frames
    text = Path(WASHERS).read_text().replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    head, rest = text.split("  classes:\n", 1)
    tail = rest[rest.index("  orientation:"):]
    p = tmp_path / "suggested.yaml"
    p.write_text(head + "  classes:\n" + "".join(f"    {c}\n" for c in classes) + tail)
    load_scenario(p)
    capsys.readouterr()
    assert main(["check", str(p), "--images", str(washer_frames)]) == 0
    out = capsys.readouterr().out
    assert "washer/flat" in out and "slug/flat" in out


def test_check_images_names_each_image_not_the_cameras_size(washer_frames, tmp_path, capsys):
    """Frames (and their golden image) scaled to 800 x 605 px, not the cell's 640 x 484
    (another camera's): one line per image, and exit 1."""
    import cv2
    for p in [*washer_frames.glob("frame_*.png"), washer_frames / "golden.png"]:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(tmp_path / p.name), cv2.resize(img, (800, 605)))
    capsys.readouterr()
    assert main(["check", WASHERS, "--images", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if "but the cell's camera takes 640x484 px" in ln]
    assert len(lines) == 15 and all(": 800x605 px, but" in ln for ln in lines)
    assert any(ln.strip().startswith("golden.png: 800x605 px") for ln in lines)
    assert "15 image(s) not 640x484 px, the camera's" in out
    capsys.readouterr()
    assert main(["check", WASHERS, "--images", str(washer_frames)]) == 0
    assert "the cell's camera takes" not in capsys.readouterr().out
