"""A part that can never be fed is named by ``feeder check`` before the run: a pick point
in a hole, a class range or ``min_area_mm2`` that cannot hold its own outline, two classes
a blob can fit both, ``principal_axis`` on a part it cannot orient, a speed in m/s."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.config import check_files
from feeder_bt.config.loader import load_scenario
from feeder_bt.config.part_checks import outline_features
from tests.support.scenarios import edited_scenario

ROOT = Path(__file__).resolve().parents[2]

WASHER_GRIPS = """    pick:
      grips: [{offset_mm: [8.5, 0]}, {offset_mm: [0, 8.5]}, {offset_mm: [-8.5, 0]}, {offset_mm: [0, -8.5]}]
      cup_radius_mm: 3
"""
# an M8 nut: 13 mm across flats, 146.4 mm²
M8 = "[[7.505, 0], [3.7527, 6.5], [-3.7527, 6.5], [-7.505, 0], [-3.7527, -6.5], [3.7527, -6.5]]"
M20 = "[[17.32, 0], [8.66, 15], [-8.66, 15], [-17.32, 0], [-8.66, -15], [8.66, -15]]"


def _check(tmp_path: Path, name: str, *edits: tuple[str, str]) -> list[str]:
    return check_files([str(edited_scenario(tmp_path, name, *edits))])


def test_the_shipped_scenarios_and_examples_pass():
    files = [*sorted((ROOT / "scenarios").glob("*.yaml")),
             ROOT / "examples" / "sprockets.yaml", ROOT / "examples" / "gussets.yaml"]
    assert check_files([str(p) for p in files]) == []


# ------------------------------------------------------------------ pick points


def test_a_ring_gripped_at_its_centroid_is_named_with_a_grip_on_the_material(tmp_path):
    out = _check(tmp_path, "washers.yaml", (WASHER_GRIPS, ""))
    assert len(out) == 1
    assert "parts.washer.shape: the pick point (the area centroid) of washer/flat lies in a " \
           "hole: every pick there misses" in out[0]
    assert "offset_mm: [8.5, 0]" in out[0]          # mid-ring, where the shipped grips are


def test_feeder_check_exits_2_on_a_ring_without_grips_and_the_ring_with_them_feeds(
        tmp_path, capsys):
    """The operator's view: ``feeder check`` exits 2 naming the hole; with the pick
    points on the ring it passes and a short run places washers, none gripped over the
    hole."""
    from feeder_bt.app.run import RunOptions, run_job
    from feeder_bt.cli.main import main
    _check(tmp_path, "washers.yaml", (WASHER_GRIPS, ""))
    assert main(["check", str(tmp_path / "washers.yaml")]) == 2
    assert "washer/flat lies in a hole" in capsys.readouterr().err
    assert main(["check", str(ROOT / "scenarios" / "washers.yaml")]) == 0
    rep = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "washers.yaml"), duration=90.0,
                             fast=True, seed=1, view="none"))
    assert rep["parts"]["retrieved"]["washer"] > 20
    assert rep["parts"]["grip_misses"]["grip_on_hole"] == 0


def test_a_grip_in_the_hole_or_a_cup_over_the_edge_is_named(tmp_path):
    out = _check(tmp_path, "washers.yaml", ("{offset_mm: [0, 8.5]}", "{offset_mm: [0, 3]}"))
    assert len(out) == 1 and "parts.washer.pick.grips[1].offset_mm" in out[0]
    assert "(0, 3) of washer/flat lies in a hole" in out[0]
    out = _check(tmp_path, "washers.yaml", ("cup_radius_mm: 3", "cup_radius_mm: 5"))
    assert len(out) == 4                            # each grip; a 7 mm ring holds no 10 mm cup
    assert "overhangs it" in out[0] and "no point of this outline holds the cup" in out[0]
    out = _check(tmp_path, "washers.yaml", ("{offset_mm: [-8.5, 0]}", "{offset_mm: [-14, 0]}"))
    assert len(out) == 1 and "(-14, 0) of washer/flat lies off the part" in out[0]


# ------------------------------------------------------------------ ranges and outlines


def test_min_area_above_a_small_nuts_outline_is_named(tmp_path):
    """An M8 nut (146 mm²) under ``min_area_mm2: 150``: many are "too small"."""
    out = _check(tmp_path, "hex_nuts.yaml", (M20, M8),
                 ("area_mm2: [750, 839]", "area_mm2: [120, 175]"),
                 ("size_mm: [34.6, 16.0]", "size_mm: [15, 6.5]"),
                 ("area_mm2: [530, 598]", "area_mm2: [80, 110]"))
    assert len(out) == 1 and "vision.min_area_mm2: 150 mm² is above" in out[0]
    assert "146.4 mm² outline" in out[0] and "too small" in out[0]
    out = _check(tmp_path, "hex_nuts.yaml", (M20, M8),
                 ("area_mm2: [750, 839]", "area_mm2: [120, 175]"),
                 ("size_mm: [34.6, 16.0]", "size_mm: [15, 6.5]"),
                 ("area_mm2: [530, 598]", "area_mm2: [80, 110]"),
                 ("min_area_mm2: 150", "min_area_mm2: 60"))
    assert out == []


@pytest.mark.parametrize("edit,key,words", [
    (("circularity: [0.93, 1.01]", "circularity: [0.5, 0.8]"),
     "vision.classes[1].circularity", "[0.5, 0.8] cannot hold slug/flat"),
    (("hole_area_mm2: [60, 100]", "hole_area_mm2: [10, 30]"),
     "vision.classes[0].hole_area_mm2", "[10, 30] cannot hold washer/flat"),
    (("holes: [1, 1]", "holes: [2, 2]"),
     "vision.classes[0].holes", "[2, 2] cannot hold washer/flat"),
    (("aspect: [2.6, 3.4]", "aspect: [1.0, 1.5]"),
     "vision.classes[2].aspect", "[1, 1.5] cannot hold slug/on_edge"),
])
def test_a_range_of_any_feature_that_cannot_hold_its_outline_is_named(tmp_path, edit, key,
                                                                      words):
    out = _check(tmp_path, "washers.yaml", edit)
    assert len(out) == 1 and f"{key}: {words}" in out[0], out
    assert "every one would fit no class" in out[0]


def test_outline_features_are_the_locators_on_the_drawn_outline():
    """The washer drawn at the cell's scale: one hole, the circularity of a disc, the area
    of the ring (452 mm² less the 79 mm² hole counts in ``area_mm2``: holes included)."""
    sc, cell = load_scenario(ROOT / "scenarios" / "washers.yaml")
    f = outline_features(sc.parts["washer"], "flat", sc.vision,
                         cell.camera.calibration.mm_per_px)
    assert f["holes"] == (1.0, 1.0)
    assert 430 < f["area_mm2"][0] <= f["area_mm2"][1] < 475
    assert 0.95 < f["circularity"][0] <= f["circularity"][1] < 1.05
    assert 55 < f["hole_area_mm2"][0] <= f["hole_area_mm2"][1] < 90


# ------------------------------------------------------------------ overlapping classes


def test_classes_a_blob_can_fit_both_are_named_with_what_tells_them_apart(tmp_path):
    out = _check(tmp_path, "washers.yaml", ("holes: [0, 0], circularity: [0.93, 1.01]", ""))
    assert len(out) == 1
    assert "vision.classes[1]: slug/flat overlaps washer/flat (vision.classes[0]) on every " \
           "feature both range over (area_mm2)" in out[0]
    assert "holes tells them apart (washer/flat measures 1, slug/flat 0)" in out[0]


def test_classes_of_one_outline_are_named_as_told_apart_by_no_feature(tmp_path):
    out = _check(tmp_path, "washers.yaml",
                 ("{part: slug, pose: flat, pickable: true, area_mm2: [420, 490], holes: [0, 0], "
                  "circularity: [0.93, 1.01]}",
                  "{part: slug, pose: flat, pickable: true, area_mm2: [420, 490], holes: [0, 0], "
                  "circularity: [0.93, 1.01]}\n    - {part: slug, pose: flat, pickable: false, "
                  "area_mm2: [430, 480], holes: [0, 0]}"))
    assert len(out) == 1 and "vision.classes[2]: slug/flat overlaps slug/flat" in out[0]
    assert "no feature tells their outlines apart" in out[0]


# ------------------------------------------------------------------ orientation and speeds


def test_principal_axis_on_a_part_of_symmetry_1_is_named(tmp_path):
    out = _check(tmp_path, "chain_links.yaml", ("    symmetry: 2\n", ""))
    assert len(out) == 1 and "vision.orientation: principal_axis cannot orient link" in out[0]
    assert "symmetry: 1" in out[0] and "turned round" in out[0]
    out = _check(tmp_path, "chain_links.yaml", ("symmetry: 2", "symmetry: 4"))
    assert len(out) == 1 and "symmetry 4 has no long axis" in out[0]
    # not placed oriented: the angle is never used
    assert _check(tmp_path, "chain_links.yaml", ("    symmetry: 2\n", ""),
                  ("orient: true", "orient: false")) == []


def test_a_speed_in_m_per_s_is_named(tmp_path):
    out = _check(tmp_path, "lenses.yaml", ("horizontal_mm_s: 150", "horizontal_mm_s: 0.15"))
    assert len(out) == 1
    assert "present.horizontal_mm_s: 0.15 mm/s: is this m/s? 150 mm/s is within the " \
           "horizontal conveyor's max_mm_s 400" in out[0]
    out = _check(tmp_path, "lenses.yaml", ("min_mm_s: 80", "min_mm_s: 0.08"))
    assert len(out) == 1 and "adjust.params.min_mm_s: 0.08 mm/s: is this m/s?" in out[0]
    assert _check(tmp_path, "lenses.yaml", ("horizontal_mm_s: 150", "horizontal_mm_s: 1")) == []


def test_a_class_that_cannot_orient_its_part_placed_oriented_is_named(tmp_path):
    """Per class: ``moment`` on a lever whose ends weigh the same (no bores), ``none``
    on a part placed oriented; the class's own ``orientation`` is the one named."""
    text = (ROOT / "scenarios" / "levers.yaml").read_text()
    bores = text[text.index("        holes_mm:\n"):text.index("    poses:\n")]
    out = _check(tmp_path, "levers.yaml", (bores, ""), ("holes: [2, 2]", "holes: [0, 0]"),
                 ("orientation: outline\n", "orientation: moment\n"))
    assert len(out) == 2                            # each pickable pose, face up and down
    assert "vision.orientation: moment cannot orient lever/face_up" in out[0]
    assert "vision.orientation: moment cannot orient lever/face_down" in out[1]
    assert "its ends weigh the same" in out[0] and "use outline" in out[0]
    out = _check(tmp_path, "levers.yaml",
                 ("mirrored: false,", "mirrored: false, orientation: none,"))
    assert len(out) == 1 and "vision.classes[0].orientation: lever/face_up is placed " \
                             "oriented (place.orient) but its class reads no angle" in out[0]
    assert _check(tmp_path, "levers.yaml") == []


def test_an_outline_that_cannot_orient_itself_is_named(tmp_path):
    """``orientation: outline`` on the lever without its bores (alike end to end: every
    blob "ambiguous", the run would place nothing), or with a least overlap its own
    drawn outline does not reach: one line for the outline both faces show."""
    text = (ROOT / "scenarios" / "levers.yaml").read_text()
    bores = text[text.index("        holes_mm:\n"):text.index("    poses:\n")]
    out = _check(tmp_path, "levers.yaml", (bores, ""), ("holes: [2, 2]", "holes: [0, 0]"))
    assert len(out) == 1 and "vision.orientation: outline cannot orient lever/face_up" in out[0]
    assert "orientation ambiguous" in out[0] and "give its symmetry" in out[0]
    out = _check(tmp_path, "levers.yaml", ("min_iou: 0.75", "min_iou: 0.99"))
    assert len(out) == 1 and "< min_iou 0.99" in out[0] and "lower outline_match.min_iou" \
        in out[0]
