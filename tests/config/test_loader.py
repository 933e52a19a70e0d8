"""Scenario and cell loader: shipped files load; every bad input is one FILE:LINE: key line."""

from __future__ import annotations

import copy
import dataclasses
import os
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder_bt.config import CellSpec, Scenario, check_files, load_cell, load_scenario
from feeder_bt.config import loader as L
from feeder_bt.core.errors import ConfigError
from feeder_bt.policy.adjusters import ADJUSTERS

ROOT = Path(__file__).resolve().parents[2]
CELL = ROOT / "cells" / "sim.yaml"
SHIPPED = sorted((ROOT / "scenarios").glob("*.yaml"))

# Line numbers below refer to this text; keep it in step with the cases.
BASE = f"""\
name: t
cell: {CELL}
tick_hz: 50
parts:
  lens:
    shape: {{disc: {{diameter_mm: 50.8}}}}
    poses:
      flat: {{probability: 0.85, pickable: true}}
      on_edge: {{silhouette: {{rect: {{size_mm: [50.8, 14.0]}}}}, probability: 0.15, pickable: false}}
    place: {{x: 1330, y: -120}}
hopper:
  parts: {{lens: 300}}
vision:
  threshold: {{method: fixed, value: 45}}
  classes:
    - {{part: lens, pose: flat, pickable: true, area_mm2: [1750, 2350]}}
    - {{part: lens, pose: on_edge, pickable: false, area_mm2: [450, 900]}}
present:
  mode: continuous
  horizontal_mm_s: 150
  incline_pct: 40
locate:
  frame_spacing_mm: 300
retrieve:
  policy: fifo
adjust:
  algorithm: water_marks
  params: {{high: 100, low: 50, min_mm_s: 80, max_mm_s: 200, median_mm_s: 150}}
"""


def write(tmp_path: Path, text: str, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def edit(text: str, *pairs: tuple[str, str]) -> str:
    for old, new in pairs:
        assert old in text, f"test text has no {old!r}"
        text = text.replace(old, new, 1)
    return text


def expect(fn, file: Path | str, line: int | None, key: str | None, *fragments: str,
           more: int = 0) -> ConfigError:
    """Assert a ConfigError whose first problem names file, line and key, on one line, with
    ``fragments``; and exactly ``more`` other problems, each on its own line."""
    with pytest.raises(ConfigError) as info:
        fn()
    problems = info.value.problems
    assert len(problems) == 1 + more, str(info.value)
    assert str(info.value).splitlines() == [str(p) for p in problems]
    e = problems[0]
    msg = str(e)
    assert "\n" not in msg and "\r" not in msg, msg
    assert e.file == str(file), msg
    assert e.line == line, msg
    assert e.key == key, msg
    prefix = f"{file}:{line}: " if line else f"{file}: "
    prefix += f"{key}: " if key else ""
    assert msg.startswith(prefix), msg
    for frag in fragments:
        assert frag in msg, msg
    assert e.exit_code == 2
    return e


# ---------------------------------------------------------------- shipped files


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_shipped_scenarios_load(path: Path) -> None:
    sc, cell = load_scenario(path)
    assert isinstance(sc, Scenario) and isinstance(cell, CellSpec)
    named = yaml.safe_load(path.read_text())["cell"]
    assert sc.path == path and sc.cell_path.resolve() == (path.parent / named).resolve()
    assert cell.path.resolve() == sc.cell_path.resolve()
    assert sc.parts and sc.vision.classes
    for part in sc.parts.values():
        assert abs(sum(p.probability for p in part.poses.values()) - 1) < 1e-6
        for name, pose in part.poses.items():
            assert pose.name == name
    assert check_files([str(path)]) == []


def test_shipped_names_cover_three_scenarios() -> None:
    assert {p.stem for p in SHIPPED} >= {"lenses", "squares", "lenses_and_squares"}


def test_sim_cell_loads() -> None:
    cell = load_cell(CELL)
    assert cell.path == CELL
    assert cell.hal == "sim"
    assert set(cell.conveyors) == {"horizontal", "incline"}
    assert cell.return_transit_s == 12.0
    assert cell.encoder.robot_start == 8000000
    assert cell.io["estop"].dir == "in" and cell.io["estop"].controller == "adept"
    assert isinstance(cell.robot.base_mm, tuple) and len(cell.robot.base_mm) == 2
    assert check_files([str(CELL)]) == []


def test_details_of_shipped_lenses() -> None:
    sc, _ = load_scenario(ROOT / "scenarios" / "lenses.yaml")
    lens = sc.parts["lens"]
    assert lens.name == "lens"
    assert lens.shape.kind == "disc" and lens.shape.diameter_mm == pytest.approx(50.8)
    assert lens.tool_offset == (0.0, 0.0, 0.0)
    on_edge = lens.poses["on_edge"]
    assert on_edge.silhouette is not None and on_edge.silhouette.size_mm == (50.8, 14.0)
    assert sc.hopper == {"lens": 300}
    assert all(isinstance(v, tuple) and len(v) == 2
               for c in sc.vision.classes for v in c.ranges.values())


def test_polygon_is_recentred_on_its_area_centroid() -> None:
    sc, _ = load_scenario(ROOT / "scenarios" / "squares.yaml")
    pts = sc.parts["square"].shape.points_mm
    a = cx = cy = 0.0
    for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1], strict=True):
        c = x0 * y1 - x1 * y0
        a, cx, cy = a + c, cx + (x0 + x1) * c, cy + (y0 + y1) * c
    assert abs(cx / (3 * a)) < 1e-9 and abs(cy / (3 * a)) < 1e-9


def test_base_text_is_valid(tmp_path: Path) -> None:
    sc, cell = load_scenario(write(tmp_path, BASE))
    assert sc.name == "t" and sc.locate.dedupe_mm == 12.0   # defaults fill the rest
    assert sc.adjust.params["median_mm_s"] == 150.0


def test_cell_argument_overrides_the_scenario_key(tmp_path: Path) -> None:
    other = write(tmp_path, CELL.read_text().replace("name: cwru-new", "name: other"),
                  "other_cell.yaml")
    p = write(tmp_path, edit(BASE, (f"cell: {CELL}", "cell: does/not/exist.yaml")))
    sc, cell = load_scenario(p, cell=other)
    assert cell.name == "other" and sc.cell_path == other


def test_cell_key_is_relative_to_the_scenario(tmp_path: Path) -> None:
    (tmp_path / "cells").mkdir()
    (tmp_path / "scen").mkdir()
    write(tmp_path / "cells", CELL.read_text(), "c.yaml")
    p = write(tmp_path / "scen", edit(BASE, (f"cell: {CELL}", "cell: ../cells/c.yaml")))
    sc, cell = load_scenario(p)
    assert sc.cell_path == tmp_path / "cells" / "c.yaml" and cell.name == "cwru-new"


def test_plain_exponent_is_a_number_and_merge_keys_work(tmp_path: Path) -> None:
    text = edit(BASE, ("horizontal_mm_s: 150", "horizontal_mm_s: 1.5e2"),
                ("locate:\n  frame_spacing_mm: 300",
                 "locate: &loc\n  frame_spacing_mm: 3e2\n  dedupe_mm: 10"))
    text += "x_unused: &dummy {a: 1}\n"
    # unknown top-level key is an error even when it only carries an anchor
    p = write(tmp_path, text)
    expect(lambda: load_scenario(p), p, 30, "x_unused", "unknown key")
    p = write(tmp_path, edit(text, ("x_unused: &dummy {a: 1}\n", "")))
    sc, _ = load_scenario(p)
    assert sc.present.horizontal_mm_s == 150.0 and sc.locate.frame_spacing_mm == 300.0
    merged = edit(BASE, ("retrieve:\n  policy: fifo",
                         "retrieve:\n  <<: {policy: earliest_deadline, too_far_mm: 900}\n"
                         "  policy: fifo"))
    sc, _ = load_scenario(write(tmp_path, merged, "m.yaml"))
    assert sc.retrieve.policy == "fifo" and sc.retrieve.too_far_mm == 900.0


def test_valid_leaf_is_accepted(tmp_path: Path) -> None:
    p = write(tmp_path, edit(BASE, ("  policy: fifo", "  policy: fifo\n"
                                                      "  leaf: feeder_bt.core.errors:ConfigError")))
    sc, _ = load_scenario(p)
    assert sc.retrieve.leaf == "feeder_bt.core.errors:ConfigError"


# ---------------------------------------------------------------- malformed scenarios

# (edits, line, key, fragments)
SCENARIO_CASES: dict[str, tuple[list[tuple[str, str]], int, str, list[str]]] = {
    "unknown_key_suggestion": (
        [("horizontal_mm_s: 150", "horizontal_mm_sec: 150")], 20, "present.horizontal_mm_sec",
        ["unknown key 'horizontal_mm_sec' (did you mean 'horizontal_mm_s'?)"]),
    "unknown_top_key": (
        [("tick_hz: 50", "tick_hertz: 50")], 3, "tick_hertz", ["did you mean 'tick_hz'"]),
    "string_for_number": (
        [("horizontal_mm_s: 150", "horizontal_mm_s: fast")], 20, "present.horizontal_mm_s",
        ["expected a number", "'fast'"]),
    "quoted_number_is_a_string": (
        [("horizontal_mm_s: 150", "horizontal_mm_s: '150'")], 20, "present.horizontal_mm_s",
        ["expected a number"]),
    "bool_for_number": (
        [("tick_hz: 50", "tick_hz: true")], 3, "tick_hz", ["expected a number", "boolean"]),
    "bool_for_number_in_flow": (
        [("place: {x: 1330,", "place: {x: yes,")], 10, "parts.lens.place.x", ["boolean true"]),
    "number_for_bool": (
        [("pickable: false}", "pickable: 0}")], 9, "parts.lens.poses.on_edge.pickable",
        ["expected true or false", "integer 0"]),
    "number_for_string": (
        [("name: t", "name: 12")], 1, "name", ["expected a string"]),
    "nan_for_number": (
        [("incline_pct: 40", "incline_pct: .nan")], 21, "present.incline_pct", ["finite"]),
    "list_for_number": (
        [("tick_hz: 50", "tick_hz: [50]")], 3, "tick_hz", ["a list"]),
    "part_beyond_any_size": (     # hypothesis found 2.4e153 mm overflow the area checks
        [("diameter_mm: 50.8", "diameter_mm: 2.4e153")], 6,
        "parts.lens.shape.disc.diameter_mm", ["beyond any part", "a unit mistake"]),
    "speed_above_cell_max": (
        [("horizontal_mm_s: 150", "horizontal_mm_s: 450")], 20, "present.horizontal_mm_s",
        ["max_mm_s 400", str(CELL)]),
    "speed_not_positive": (
        [("horizontal_mm_s: 150", "horizontal_mm_s: 0")], 20, "present.horizontal_mm_s",
        ["must be > 0"]),
    "incline_speed_above_cell_max": (
        [("horizontal_mm_s: 150", "horizontal_mm_s: 300"), ("incline_pct: 40", "incline_pct: 150")],
        21, "present.incline_pct", ["450 mm/s", "max_mm_s 400"]),
    "incline_pct_range": (
        [("incline_pct: 40", "incline_pct: 201")], 21, "present.incline_pct", ["[0, 200]"]),
    "tick_hz_range": (
        [("tick_hz: 50", "tick_hz: 4")], 3, "tick_hz", ["[5, 1000]", "got 4"]),
    "robot_speed_pct_zero": (
        [("policy: fifo", "policy: fifo\n  robot_speed_pct: 0")], 26,
        "retrieve.robot_speed_pct", ["[1, 200]"]),
    "probabilities_do_not_sum_to_one": (
        [("0.15, pickable", "0.10, pickable")], 7, "parts.lens.poses",
        ["sum to 1", "0.95"]),
    "probability_out_of_range": (
        [("probability: 0.85", "probability: 1.15"), ("0.15, pickable", "-0.15, pickable")],
        8, "parts.lens.poses.flat.probability", ["[0, 1]"]),
    "no_pickable_pose": (
        [("pickable: true}\n      on_edge", "pickable: false}\n      on_edge")], 7,
        "parts.lens.poses", ["pickable pose"]),
    "class_unknown_part": (
        [("part: lens, pose: on_edge", "part: lense, pose: on_edge")], 17,
        "vision.classes[1].part", ["unknown part 'lense'", "did you mean 'lens'"]),
    "class_unknown_pose": (
        [("pose: flat,", "pose: flatt,")], 16, "vision.classes[0].pose",
        ["no pose 'flatt'", "did you mean 'flat'"]),
    "class_unknown_feature": (
        [("area_mm2: [450", "area_mm: [450")], 17, "vision.classes[1].area_mm",
        ["did you mean 'area_mm2'"]),
    "class_range_reversed": (
        [("[1750, 2350]", "[2350, 1750]")], 16, "vision.classes[0].area_mm2", ["lo > hi"]),
    "class_range_wrong_length": (
        [("[1750, 2350]", "[1750]")], 16, "vision.classes[0].area_mm2", ["2 values, got 1"]),
    "class_range_bad_item": (
        [("[1750, 2350]", "[1750, big]")], 16, "vision.classes[0].area_mm2[1]",
        ["expected a number"]),
    "class_missing_pickable": (
        [("pose: flat, pickable: true,", "pose: flat,")], 16, "vision.classes[0].pickable",
        ["missing required key 'pickable'"]),
    "duplicate_key": (
        [("  mode: continuous\n", "  mode: continuous\n  mode: incremental\n")], 20,
        "present.mode", ["duplicate key 'mode'", "line 19"]),
    "duplicate_part": (
        [("      on_edge:", "      flat:")], 9, "parts.lens.poses.flat", ["duplicate key"]),
    "missing_required_key_in_flow": (
        [(", pickable: false}", "}")], 9, "parts.lens.poses.on_edge.pickable",
        ["missing required key 'pickable'"]),
    "missing_required_key_in_block": (
        [("    place: {x: 1330, y: -120}\n", "")], 5, "parts.lens.place",
        ["missing required key 'place'"]),
    "missing_top_level_key": (
        [("name: t\n", "")], 1, "name", ["missing required key 'name'"]),
    "missing_hopper": (
        [("hopper:\n  parts: {lens: 300}\n", "")], 1, "hopper", ["missing required key"]),
    "enum_with_suggestion": (
        [("mode: continuous", "mode: continous")], 19, "present.mode",
        ["continuous, incremental", "did you mean 'continuous'"]),
    "threshold_method": (
        [("method: fixed", "method: otsus")], 14, "vision.threshold.method", ["otsu"]),
    "orientation": (
        [("  threshold:", "  orientation: principal\n  threshold:")], 14,
        "vision.orientation", ["principal_axis"]),
    "retrieve_policy": (
        [("policy: fifo", "policy: lifo")], 25, "retrieve.policy", ["fifo, earliest_deadline"]),
    "adjust_algorithm": (
        [("algorithm: water_marks", "algorithm: watermarks")], 27, "adjust.algorithm",
        ["did you mean 'water_marks'"]),
    "adjust_unknown_param": (
        [("low: 50", "lowe: 50")], 28, "adjust.params.lowe", ["did you mean 'low'"]),
    "adjust_low_not_below_high": (
        [("low: 50", "low: 100")], 28, "adjust.params.low", ["< high"]),
    "adjust_median_outside": (
        [("median_mm_s: 150", "median_mm_s: 250")], 28, "adjust.params.median_mm_s",
        ["<= max_mm_s"]),
    "adjust_gain_checked_by_the_adjuster": (
        [("low: 50,", "low: 50, gain: 1.5,")], 28, "adjust.params.gain", ["[0, 1]"]),
    "adjust_speed_above_cell": (
        [("max_mm_s: 200, median", "max_mm_s: 500, median")], 28, "adjust.params.max_mm_s",
        ["max_mm_s 400"]),
    "adjust_none_takes_no_params": (
        [("algorithm: water_marks", "algorithm: none")], 28, "adjust.params.high",
        ["takes no params"]),
    "adjust_param_type": (
        [("high: 100", "high: lots")], 28,
        "adjust.params.high", ["expected a number"]),
    "hopper_unknown_part": (
        [("parts: {lens: 300}", "parts: {lens: 300, len: 3}")], 12, "hopper.parts.len",
        ["unknown part 'len'", "did you mean 'lens'"]),
    "hopper_negative": (
        [("parts: {lens: 300}", "parts: {lens: -1}")], 12, "hopper.parts.lens", [">= 0"]),
    "hopper_all_zero": (
        [("parts: {lens: 300}", "parts: {lens: 0}")], 12, "hopper.parts", ["count > 0"]),
    "hopper_float_count": (
        [("parts: {lens: 300}", "parts: {lens: 2.5}")], 12, "hopper.parts.lens",
        ["expected an integer"]),
    "hopper_not_wrapped": (
        [("  parts: {lens: 300}", "  lens: 300")], 12, "hopper.lens", ["unknown key 'lens'"]),
    "sequence_unknown_part": (
        [("policy: fifo", "policy: fifo\n  sequence: [lens, nut]")], 26,
        "retrieve.sequence[1]", ["unknown part 'nut'"]),
    "frame_spacing_too_large": (
        [("frame_spacing_mm: 300", "frame_spacing_mm: 440")], 23, "locate.frame_spacing_mm",
        ["431.28", "'lens'"]),   # 484 px at the calibrated 0.99995 mm/px, less 52.7 mm (on edge)
    "frame_spacing_not_positive": (
        [("frame_spacing_mm: 300", "frame_spacing_mm: -1")], 23, "locate.frame_spacing_mm",
        ["> 0"]),
    "bad_leaf_import": (
        [("frame_spacing_mm: 300", "frame_spacing_mm: 300\n  leaf: nosuch_pkg.mod:Thing")],
        24, "locate.leaf", ["cannot import module 'nosuch_pkg.mod'", "nosuch_pkg"]),
    "bad_leaf_format": (
        [("frame_spacing_mm: 300", "frame_spacing_mm: 300\n  leaf: just_a_name")],
        24, "locate.leaf", ["package.module:Class"]),
    "leaf_missing_class": (
        [("frame_spacing_mm: 300", "frame_spacing_mm: 300\n  leaf: feeder_bt.core.errors:ConfigEror")],
        24, "locate.leaf", ["no class 'ConfigEror'", "did you mean 'ConfigError'"]),
    "leaf_not_a_class": (
        [("frame_spacing_mm: 300",
          "frame_spacing_mm: 300\n  leaf: feeder_bt.config.loader:load_cell")],
        24, "locate.leaf", ["not a class"]),
    "missing_cell_file": (
        [(f"cell: {CELL}", "cell: ../cells/nope.yaml")], 2, "cell",
        ["cell file '../cells/nope.yaml' not found"]),
    "cell_key_not_a_string": (
        [(f"cell: {CELL}", "cell: [a]")], 2, "cell", ["expected a single value"]),
    "shape_two_kinds": (
        [("{disc: {diameter_mm: 50.8}}", "{disc: {diameter_mm: 50.8}, rect: {size_mm: [1, 2]}}")],
        6, "parts.lens.shape", ["exactly one shape kind"]),
    "shape_unknown_kind": (
        [("{disc: {diameter_mm", "{discs: {diameter_mm")], 6, "parts.lens.shape.discs",
        ["did you mean 'disc'"]),
    "shape_wrong_field": (
        [("{disc: {diameter_mm", "{disc: {size_mm")], 6, "parts.lens.shape.disc.size_mm",
        ["unknown key 'size_mm' (known: diameter_mm, hole_mm)"]),
    "shape_negative_diameter": (
        [("diameter_mm: 50.8", "diameter_mm: -50.8")], 6,
        "parts.lens.shape.disc.diameter_mm", ["> 0"]),
    "polygon_collinear": (
        [("{disc: {diameter_mm: 50.8}}", "{polygon: {points_mm: [[0, 0], [1, 1], [2, 2]]}}")],
        6, "parts.lens.shape.polygon.points_mm", ["no area"]),
    "polygon_bad_point": (
        [("{disc: {diameter_mm: 50.8}}", "{polygon: {points_mm: [[0, 0], [1, 0], [1]]}}")],
        6, "parts.lens.shape.polygon.points_mm[2]", ["2 values"]),
    "silhouette_rect": (
        [("size_mm: [50.8, 14.0]", "size_mm: 3")],
        9, "parts.lens.poses.on_edge.silhouette.rect.size_mm", ["expected a list"]),
    "tool_offset_length": (
        [("    place:", "    tool_offset: [0, 0]\n    place:")], 10, "parts.lens.tool_offset",
        ["3 values, got 2"]),
    "key_read_as_bool": (
        [("      on_edge:", "      on:")], 9, "parts.lens.poses", ["quote it"]),
    "parts_not_a_mapping": (
        [("parts:\n  lens:\n", "parts: [lens]\nunused:\n  lens:\n")], 4, "parts",
        ["expected a mapping", "a list"]),
    "threshold_block_even": (
        [("method: fixed, value: 45", "method: adaptive, block_px: 50")], 14,
        "vision.threshold.block_px", ["odd"]),
    "null_for_required_number": (
        [("tick_hz: 50", "tick_hz:")], 3, "tick_hz", ["null"]),
    "bad_tag": (
        [("tick_hz: 50", "tick_hz: !weird 50")], 3, "tick_hz", ["cannot read value"]),
}


# Cases whose edits make more than one independent mistake: how many more are listed.
MORE_PROBLEMS = {
    "probability_out_of_range": 1,      # both poses' probabilities are out of range
    "parts_not_a_mapping": 1,           # and the key `unused` the edit adds
    "shape_wrong_field": 1,             # and diameter_mm is missing (size_mm is no misspelling)
}


@pytest.mark.parametrize("case", sorted(SCENARIO_CASES))
def test_malformed_scenario(tmp_path: Path, case: str) -> None:
    edits, line, key, fragments = SCENARIO_CASES[case]
    p = write(tmp_path, edit(BASE, *edits))
    more = MORE_PROBLEMS.get(case, 0)
    e = expect(lambda: load_scenario(p), p, line, key, *fragments, more=more)
    assert check_files([str(p)])[0] == str(e) and len(check_files([str(p)])) == 1 + more


def test_yaml_syntax_error(tmp_path: Path) -> None:
    p = write(tmp_path, edit(BASE, ("place: {x: 1330, y: -120}", "place: {x: 1330, y: -120")))
    expect(lambda: load_scenario(p), p, 11, None, "YAML syntax error", "flow mapping",
           "line 10")


def test_yaml_bad_indentation(tmp_path: Path) -> None:
    p = write(tmp_path, edit(BASE, ("  horizontal_mm_s: 150", " horizontal_mm_s: 150")))
    expect(lambda: load_scenario(p), p, 20, None, "YAML syntax error")


def test_yaml_tab_indentation(tmp_path: Path) -> None:
    p = write(tmp_path, edit(BASE, ("  horizontal_mm_s: 150", "\thorizontal_mm_s: 150")))
    expect(lambda: load_scenario(p), p, 20, None, "YAML syntax error", "tab")


def test_two_documents(tmp_path: Path) -> None:
    p = write(tmp_path, BASE + "---\nname: again\n")
    expect(lambda: load_scenario(p), p, 29, None, "single document")


def test_non_mapping_file(tmp_path: Path) -> None:
    p = write(tmp_path, "- a\n- b\n")
    expect(lambda: load_scenario(p), p, 1, None, "expected a mapping", "a list")
    p = write(tmp_path, "# only a comment\njust words\n", "w.yaml")
    expect(lambda: load_scenario(p), p, 2, None, "expected a mapping", "string 'just words'")


def test_empty_file(tmp_path: Path) -> None:
    p = write(tmp_path, "# nothing\n")
    expect(lambda: load_scenario(p), p, 1, None, "empty")


def test_missing_file(tmp_path: Path) -> None:
    p = tmp_path / "nope.yaml"
    expect(lambda: load_scenario(p), p, None, None, "file not found")
    expect(lambda: load_cell(p), p, None, None, "file not found")


def test_missing_cell_override(tmp_path: Path) -> None:
    p = write(tmp_path, BASE)
    c = tmp_path / "no_cell.yaml"
    expect(lambda: load_scenario(p, cell=c), c, None, None, "file not found")


def test_directory_and_binary_files(tmp_path: Path) -> None:
    expect(lambda: load_cell(tmp_path), tmp_path, None, None, "directory")
    p = tmp_path / "bin.yaml"
    p.write_bytes(b"name: \xff\xfe\n")
    expect(lambda: load_cell(p), p, None, None, "not UTF-8")
    p = write(tmp_path, "name: a\x07b\n", "ctl.yaml")
    expect(lambda: load_cell(p), p, 1, None, "unacceptable character")


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root reads anything")
def test_unreadable_file(tmp_path: Path) -> None:
    p = write(tmp_path, BASE)
    p.chmod(0)
    try:
        expect(lambda: load_scenario(p), p, None, None, "cannot read")
    finally:
        p.chmod(0o644)


def test_missing_cell_key_without_override(tmp_path: Path) -> None:
    p = write(tmp_path, edit(BASE, (f"cell: {CELL}\n", "")))
    expect(lambda: load_scenario(p), p, 1, "cell", "missing required key 'cell'")
    load_scenario(p, cell=CELL)   # fine with an override


def test_errors_in_the_cell_name_the_cell_file(tmp_path: Path) -> None:
    text = edit(CELL.read_text(), ("max_mm_s: 400, accel", "max_mm_sec: 400, accel"))
    write(tmp_path, text, "c.yaml")
    p = write(tmp_path, edit(BASE, (f"cell: {CELL}", "cell: c.yaml")))
    expect(lambda: load_scenario(p), p.parent / "c.yaml", _line_of(text, "max_mm_sec"),
           "conveyors.horizontal.max_mm_sec",
           "did you mean 'max_mm_s'")


def test_cell_speed_limit_is_the_cells(tmp_path: Path) -> None:
    c = write(tmp_path, edit(CELL.read_text(), ("max_mm_s: 400, accel", "max_mm_s: 120, accel")),
              "c.yaml")
    p = write(tmp_path, BASE)
    e = expect(lambda: load_scenario(p, cell=c), p, 20, "present.horizontal_mm_s",
               "max_mm_s 120", str(c), more=2)
    # the adjuster's speeds are above it too, each listed on its own line
    assert [(q.line, q.key) for q in load_problems(p, cell=c)[1:]] == [
        (28, "adjust.params.max_mm_s"), (28, "adjust.params.median_mm_s")], e


def test_adjuster_default_speed_is_checked_against_the_cell(tmp_path: Path) -> None:
    c = write(tmp_path, edit(CELL.read_text(), ("max_mm_s: 400, accel", "max_mm_s: 250, accel")),
              "c.yaml")
    p = write(tmp_path, edit(BASE, ("max_mm_s: 200, ", "")))
    expect(lambda: load_scenario(p, cell=c), p, 28, "adjust.params.max_mm_s",
           "300 mm/s (the water_marks default)", "max_mm_s 250")


# ---------------------------------------------------------------- malformed cells

# (edits, a text on the offending line of the edited file, key, fragments): the line is
# found in the edited text, so cells/sim.yaml may gain comments or keys without breaking these.
CELL_CASES: dict[str, tuple[list[tuple[str, str]], str, str, list[str]]] = {
    "unknown_conveyor": (
        [("  incline:", "  inclined:")], "  inclined:", "conveyors.inclined",
        ["did you mean 'incline'"]),
    "return_unknown_key": (
        [("{transit_s: 12.0}", "{transit: 12.0}")], "transit:", "conveyors.return.transit",
        ["did you mean 'transit_s'"]),
    "return_negative": (
        [("{transit_s: 12.0}", "{transit_s: -1}")], "transit_s:", "conveyors.return.transit_s",
        [">= 0"]),
    "hal_enum": (
        [("hal: sim", "hal: simulated")], "hal:", "hal", ["sim, emulated, real"]),
    "io_dir": (
        [("bit: 1, dir: in}", "bit: 1, dir: inout}")], "estop:", "io.estop.dir", ["in, out"]),
    "io_missing_controller": (
        [("{controller: adept, bit: 2, dir: out}", "{bit: 2}")], "vacuum:",
        "io.vacuum.controller", ["missing required key"]),
    "encoder_bits_bool": (
        [("conveyor_bits: 32", "conveyor_bits: no")], "conveyor_bits:", "encoder.conveyor_bits",
        ["expected an integer", "boolean false"]),
    "encoder_start_too_big": (
        [("robot_start: 8000000", "robot_start: 80000000")], "robot_start:",
        "encoder.robot_start", ["2**robot_bits"]),
    "camera_mm_per_px": (
        [("mm_per_px: 1.0", "mm_per_px: 0")], "mm_per_px:", "camera.sim_truth.mm_per_px",
        ["> 0"]),
    "robot_inner_reach": (
        [("inner_reach_mm: 160", "inner_reach_mm: 700")], "inner_reach_mm:",
        "robot.inner_reach_mm", ["< robot.reach_mm"]),
    "robot_window_outside_reach": (
        [("grip_tolerance_mm: 4.0", "grip_tolerance_mm: 4.0\n  belt_window_mm: [700, 1150]")],
        "belt_window_mm:", "robot.belt_window_mm",
        ["upstream limit 700 mm is outside the arm's reach over the belt (770-1219 mm"]),
    "robot_base_type": (
        [("base_mm: [1370, 305]", "base_mm: 1370")], "base_mm:", "robot.base_mm",
        ["expected a list"]),
    "missing_name": (
        [("name: cwru-new\n", "")], "hal:", "name", ["missing required key"]),
    "duplicate_section": (
        [("hal: sim\n", "hal: sim\nhal: real\n")], "hal: real", "hal", ["duplicate"]),
    "unknown_section": (
        [("hal: sim\n", "hal: sim\ncamerra: {}\n")], "camerra:", "camerra",
        ["did you mean 'camera'"]),
}


def load_problems(path: Path, **kwargs) -> list[ConfigError]:
    """Every problem ``load_scenario`` lists for ``path`` (none when it loads)."""
    try:
        load_scenario(path, **kwargs)
    except ConfigError as e:
        return e.problems
    return []


def _line_of(text: str, needle: str) -> int:
    return next(i for i, ln in enumerate(text.splitlines(), 1)
                if needle in ln and not ln.lstrip().startswith("#"))


@pytest.mark.parametrize("case", sorted(CELL_CASES))
def test_malformed_cell(tmp_path: Path, case: str) -> None:
    edits, needle, key, fragments = CELL_CASES[case]
    text = edit(CELL.read_text(), *edits)
    p = write(tmp_path, text, "cell.yaml")
    expect(lambda: load_cell(p), p, _line_of(text, needle), key, *fragments)


# ---------------------------------------------------------------- check_files


def test_check_files_one_line_per_bad_file(tmp_path: Path) -> None:
    bad1 = write(tmp_path, edit(BASE, ("tick_hz: 50", "tick_hz: 1")), "bad1.yaml")
    bad2 = write(tmp_path, "key: [unclosed\n", "bad2.yaml")
    celltext = edit(CELL.read_text(), ("hal: sim", "hal: simm"))
    badcell = write(tmp_path, celltext, "cell.yaml")
    good = [str(p) for p in SHIPPED] + [str(CELL)]
    out = check_files(good + [str(bad1), str(bad2), str(badcell), str(tmp_path / "nope.yaml")])
    assert len(out) == 4
    assert out[0].startswith(f"{bad1}:3: tick_hz: ")
    assert out[1].startswith(f"{bad2}:")
    assert out[2].startswith(f"{badcell}:{_line_of(celltext, 'hal:')}: hal: ")
    assert out[3] == f"{tmp_path / 'nope.yaml'}: file not found"
    assert all("\n" not in line for line in out)
    assert check_files(good) == []


# ---------------------------------------------------------------- tables and genericity


def test_tables_name_real_model_fields() -> None:
    """A renamed model field must not leave a check silently doing nothing."""
    for cls, fname in list(L.RANGES) + list(L.ENUMS):
        assert fname in {f.name for f in dataclasses.fields(cls)}, (cls.__name__, fname)
    assert set(L.ADJUST_ALGORITHMS) == set(L.ADJUST_PARAMS)
    for algo, table in L.ADJUST_PARAMS.items():   # the loader's table and the adjusters agree
        assert set(table) == set(ADJUSTERS[algo].PARAMS), algo
    assert "area_mm2" in L.FEATURES


def test_model_defaults_are_allowed_values() -> None:
    for (cls, fname), allowed in L.ENUMS.items():
        f = next(f for f in dataclasses.fields(cls) if f.name == fname)
        if f.default is not dataclasses.MISSING and f.default is not None:   # None: not set
            assert f.default in allowed, (cls.__name__, fname)
    for (cls, fname), rng in L.RANGES.items():
        f = next(f for f in dataclasses.fields(cls) if f.name == fname)
        if isinstance(f.default, int | float):
            assert rng.contains(f.default), (cls.__name__, fname)


@dataclasses.dataclass
class _Inner:
    name: str
    speed_mm_s: float
    tags: list[str] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class _Outer:
    items: dict[str, _Inner]
    limit: int = 3
    maybe: tuple[float, float] | None = None
    flag: bool = False


def test_walker_is_generic_over_dataclasses(tmp_path: Path) -> None:
    """A field added to a model dataclass is a YAML key with no loader change."""
    text = "items:\n  a: {speed_mm_s: 2, tags: [x]}\nmaybe: [1, 2]\nflag: true\n"
    node = yaml.compose(text, Loader=yaml.SafeLoader)
    ctx = L._Ctx("mem.yaml")
    out = ctx.dataclass(_Outer, node, "")
    assert out == _Outer(items={"a": _Inner("a", 2.0, ["x"])}, maybe=(1.0, 2.0), flag=True)
    node = yaml.compose("items:\n  a: {speed_mm_s: 2, tag: [x]}\n", Loader=yaml.SafeLoader)
    ctx = L._Ctx("mem.yaml")
    ctx.dataclass(_Outer, node, "")          # an unknown key is listed, the rest still built
    expect(ctx.raise_problems, "mem.yaml", 2, "items.a.tag", "did you mean 'tags'")


# ---------------------------------------------------------------- property tests

_SCALARS = st.one_of(
    st.none(), st.booleans(), st.integers(min_value=-(10**20), max_value=10**20),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=12),
    st.sampled_from(["lens", "square", "flat", "face_up", "fifo", "otsu", "none",
                     "feeder_bt.core.errors:ConfigError", "no.such:Thing", "1e3", "[]", "{}"]),
)


def _paths(data, prefix=()) -> list[tuple]:
    out = []
    if isinstance(data, dict):
        items = data.items()
    elif isinstance(data, list):
        items = enumerate(data)
    else:
        return out
    for k, v in items:
        out.append(prefix + (k,))
        out.extend(_paths(v, prefix + (k,)))
    return out


def _mutate(data, path, op, value) -> None:
    parent = data
    for k in path[:-1]:
        parent = parent[k]
    k = path[-1]
    if op == "delete":
        del parent[k]
    else:
        parent[k] = value


def _load_must_not_crash(text: str, cell_file: Path | None = None) -> None:
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "s.yaml"
        p.write_text(text, encoding="utf-8")
        try:
            if cell_file is None:
                load_scenario(p)
            else:
                load_cell(p)
        except ConfigError as e:
            for problem in e.problems:
                assert "\n" not in str(problem) and problem.file == str(p)


def _mutated(draw, base: dict) -> dict:
    data = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 4))):
        paths = _paths(data)
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        op = draw(st.sampled_from(["delete", "replace"]))
        _mutate(data, path, op, draw(_SCALARS))
    return data


_SCENARIO_DATA = {p.stem: yaml.safe_load(p.read_text()) for p in SHIPPED}
for _d in _SCENARIO_DATA.values():
    _d["cell"] = str(CELL)
_CELL_DATA = yaml.safe_load(CELL.read_text())


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_mutated_scenarios_load_or_raise_config_error(data) -> None:
    base = _SCENARIO_DATA[data.draw(st.sampled_from(sorted(_SCENARIO_DATA)))]
    text = yaml.safe_dump(_mutated(data.draw, base), allow_unicode=True)
    _load_must_not_crash(text)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.data())
def test_mutated_cells_load_or_raise_config_error(data) -> None:
    text = yaml.safe_dump(_mutated(data.draw, _CELL_DATA), allow_unicode=True)
    _load_must_not_crash(text, cell_file=CELL)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(pos=st.integers(0, len(BASE)), junk=st.text(max_size=6).filter(
    lambda s: all(c != "\x00" and not 0xD800 <= ord(c) <= 0xDFFF for c in s)),
    cut=st.integers(0, 8))
def test_mutated_text_loads_or_raises_config_error(pos: int, junk: str, cut: int) -> None:
    _load_must_not_crash(BASE[:pos] + junk + BASE[pos + cut:])
