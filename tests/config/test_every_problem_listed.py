"""Every problem of a file is listed, not only the first: each on its own line
``FILE:LINE: dotted.key: what``, in file order, for scenarios (with their cell), cells and
fault plans; ``feeder check`` prints them all and a count, ``feeder run`` prints them all
and exits 2; at most ``MAX_PROBLEMS`` are shown, then how many more."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.cli.main import main
from feeder_bt.config.files import load_fault_plan
from feeder_bt.config.loader import load_cell, load_scenario
from feeder_bt.core.errors import MAX_PROBLEMS, ConfigError

ROOT = Path(__file__).resolve().parents[2]
CELL = ROOT / "cells" / "sim.yaml"
LENSES = (ROOT / "scenarios" / "lenses.yaml").read_text()
SHIFT = (ROOT / "faults" / "shift.yaml").read_text()


def edited(text: str, *pairs: tuple[str, str]) -> str:
    for old, new in pairs:
        assert old in text, old
        text = text.replace(old, new, 1)
    return text


def scenario(tmp_path: Path, *pairs: tuple[str, str], cell: Path = CELL) -> Path:
    p = tmp_path / "bad.yaml"
    p.write_text(edited(LENSES, ("cell: ../cells/sim.yaml", f"cell: {cell}"), *pairs))
    return p


def problems(fn, *args) -> list[ConfigError]:
    with pytest.raises(ConfigError) as info:
        fn(*args)
    e = info.value
    assert str(e).splitlines() == e.lines()          # the message: one line per problem
    assert all("\n" not in str(p) for p in e.problems)
    assert e.exit_code == 2
    return e.problems


def line_of(path: Path, needle: str) -> int:
    return next(i for i, s in enumerate(path.read_text().splitlines(), 1) if needle in s)


# Three misspelt keys and a speed above the cell's conveyor: four lines, in file order
# (the speed is checked against the cell although the file has other mistakes).
FOUR = [("tick_hz: 200", "tick_hzz: 200"), ("horizontal_mm_s: 150", "horizontal_mm_s: 450"),
        ("frame_spacing_mm: 300", "frame_spacng_mm: 300"), ("policy: fifo", "polcy: fifo")]


def test_three_misspelt_keys_and_a_speed_are_four_lines_in_file_order(tmp_path):
    p = scenario(tmp_path, *FOUR)
    got = [(e.file, e.line, e.key) for e in problems(load_scenario, p)]
    assert got == [(str(p), line_of(p, "tick_hzz"), "tick_hzz"),
                   (str(p), line_of(p, "horizontal_mm_s"), "present.horizontal_mm_s"),
                   (str(p), line_of(p, "frame_spacng_mm"), "locate.frame_spacng_mm"),
                   (str(p), line_of(p, "polcy"), "retrieve.polcy")]
    whats = [e.what for e in problems(load_scenario, p)]
    assert "did you mean 'tick_hz'" in whats[0] and "max_mm_s 400" in whats[1]
    assert "did you mean 'frame_spacing_mm'" in whats[2] and "did you mean 'policy'" in whats[3]


def test_wrong_types_and_ranges_of_one_mapping_are_each_listed(tmp_path):
    p = scenario(tmp_path, ("method: fixed, value: 80", "method: fixd, value: 800"),
                 ("incline_pct: 40", "incline_pct: lots"), ("mode: continuous", "mode: 3"))
    got = [(e.key, e.what.split(",")[0]) for e in problems(load_scenario, p)]
    assert got == [("vision.threshold.method", "must be one of fixed"),
                   ("vision.threshold.value", "must be in [0"),
                   ("present.mode", "expected a string"),
                   ("present.incline_pct", "expected a number")]


def test_items_of_lists_and_entries_of_mappings_are_each_checked(tmp_path):
    """Two bad vision classes and two bad poses: four problems, not the first one."""
    p = scenario(tmp_path, ("area_mm2: [1800, 2300]", "area_mm2: [2300, 1800]"),
                 ("area_mm2: [550, 900]", "area_mm2: [550]"),
                 ("{probability: 0.85,", "{probability: 1.85,"),
                 ("pickable: false, silhouette", "pickable: nope, silhouette"))
    keys = [e.key for e in problems(load_scenario, p)]
    assert sorted(keys) == sorted(["vision.classes[0].area_mm2", "vision.classes[1].area_mm2",
                                   "parts.lens.poses.flat.probability",
                                   "parts.lens.poses.on_edge.pickable"])


def test_a_misspelt_required_key_is_one_problem_not_two(tmp_path):
    p = scenario(tmp_path, ("hopper:", "hoper:"))
    (e,) = problems(load_scenario, p)
    assert e.key == "hoper" and "did you mean 'hopper'" in e.what


def test_a_duplicate_key_stops_the_checks_it_would_mislead(tmp_path):
    """The duplicate's entry is left out, so the pose probabilities and the classes' poses
    are not checked against what remains (they would be wrong for the wrong reason)."""
    text = LENSES.replace("cell: ../cells/sim.yaml", f"cell: {CELL}")
    text = text.replace("      on_edge:", "      flat:", 1)
    p = tmp_path / "dup.yaml"
    p.write_text(text)
    (e,) = problems(load_scenario, p)
    assert "duplicate key 'flat'" in e.what


def test_problems_of_the_scenario_and_of_its_cell_are_listed_together(tmp_path):
    cell = tmp_path / "cell.yaml"
    cell.write_text(edited(CELL.read_text(), ("hal: sim", "hal: simm"),
                           ("max_mm_s: 400, accel", "max_mm_sec: 400, accel")))
    p = scenario(tmp_path, ("tick_hz: 200", "tick_hz: 2"), cell=cell)
    got = [(Path(e.file).name, e.key) for e in problems(load_scenario, p)]
    assert got == [("bad.yaml", "tick_hz"), ("cell.yaml", "hal"),
                   ("cell.yaml", "conveyors.horizontal.max_mm_sec")]


def test_a_cell_lists_every_problem(tmp_path):
    p = tmp_path / "cell.yaml"
    p.write_text(edited(CELL.read_text(), ("hal: sim", "hal: simm"),
                        ("inner_reach_mm: 160", "inner_reach_mm: 7000"),
                        ("conveyor_bits: 32", "conveyor_bits: no")))
    # a bad number or word stands in by its default, so the cross-key inner reach is
    # judged too; checks across the broken section (the encoder) wait
    assert [e.key for e in problems(load_cell, p)] == ["hal", "encoder.conveyor_bits",
                                                       "robot.inner_reach_mm"]
    # the cross-key check (inner reach) runs once the cell is whole
    p.write_text(edited(CELL.read_text(), ("hal: sim", "hal: sim\nspare: 1"),
                        ("inner_reach_mm: 160", "inner_reach_mm: 7000")))
    assert [e.key for e in problems(load_cell, p)] == ["spare", "robot.inner_reach_mm"]


def test_a_fault_plan_lists_every_problem(tmp_path):
    p = tmp_path / "plan.yaml"
    p.write_text(edited(SHIFT, ("seed: 1", "sed: 1"),
                        ("servo_timeout: {per_pick", "servo_timout: {per_pick"),
                        ("kind: estop, release_after_s: 60}", "kind: estop, release_after: 60}"),
                        ("{at_s: 21600, kind: estop,", "{at_s: 21600, kind: estop, device: adept,")))
    got = [(e.line, e.key) for e in problems(load_fault_plan, p)]
    assert got == [(line_of(p, "sed: 1"), "sed"),
                   (line_of(p, "servo_timout"), "rates.servo_timout"),
                   (line_of(p, "release_after:"), "scripted[0].release_after"),
                   (line_of(p, "device: adept"), "scripted[1].device")]   # checked across keys
    # a wrong rate, a wrong grab unit and a negative time: each listed
    p.write_text(edited(SHIFT, ("per_pick: 0.005", "per_pick: 5"),
                        ("grab_failed: {per_frame: 0.002}", "grab_failed: {per_pick: 0.002}"),
                        ("{at_s: 7200, kind: estop", "{at_s: -5, kind: estop")))
    assert [e.key for e in problems(load_fault_plan, p)] == [
        "rates.servo_timeout.per_pick", "rates.grab_failed.per_pick", "scripted[0].at_s"]


def test_at_most_max_problems_are_shown_then_how_many_more(tmp_path):
    extra = "".join(f"spare_{i}: {i}\n" for i in range(MAX_PROBLEMS + 7))
    p = scenario(tmp_path, ("tick_hz: 200", f"{extra}tick_hz: 200"))
    with pytest.raises(ConfigError) as info:
        load_scenario(p)
    e = info.value
    assert len(e.problems) == MAX_PROBLEMS + 7
    lines = str(e).splitlines()
    assert len(lines) == MAX_PROBLEMS + 1 and lines[-1] == "... and 7 more problems"
    assert lines[0].startswith(f"{p}:{line_of(p, 'spare_0')}: spare_0: unknown key")


def test_check_prints_every_problem_of_every_file_and_a_count(tmp_path, capsys):
    bad = scenario(tmp_path, *FOUR)
    plan = tmp_path / "plan.yaml"
    plan.write_text(edited(SHIFT, ("seed: 1", "seed: one")))
    assert main(["check", str(bad), str(CELL), str(plan)]) == 2
    out, err = capsys.readouterr()
    assert out.splitlines() == [f"ok: {CELL} (a cell description)",
                                "5 problems in 2 of 3 files"]
    err = err.splitlines()
    assert len(err) == 5 and all(s.startswith(f"{bad}:") for s in err[:4])
    assert err[0].endswith("(read as a scenario)") and "polcy" in err[3]
    assert err[4].startswith(f"{plan}:") and err[4].endswith("(read as a fault plan)")


def test_run_prints_every_problem_one_line_each_and_exits_2(tmp_path, capsys):
    bad = scenario(tmp_path, *FOUR)
    assert main(["run", str(bad), "--fast", "--no-db"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 4 and all(s.startswith(f"feeder: {bad}:") for s in err)
    assert "Traceback" not in "".join(err)


def test_check_says_what_a_file_of_no_kind_was_read_as(tmp_path, capsys):
    odd = tmp_path / "odd.yaml"
    odd.write_text("foo: 1\n")
    assert main(["check", str(odd)]) == 2
    first = capsys.readouterr().err.splitlines()[0]
    assert first.endswith("(read as a scenario: no key tells its kind)"), first


def test_check_says_the_kind_on_the_files_own_line(tmp_path, capsys):
    """A scenario's cell's problems name the cell file; the kind goes on the scenario's."""
    cell = tmp_path / "cell.yaml"
    cell.write_text(edited(CELL.read_text(), ("hal: sim", "hal: simm")))
    p = scenario(tmp_path, cell=cell)
    assert main(["check", str(p)]) == 2
    (only,) = capsys.readouterr().err.splitlines()
    assert only.startswith(f"{cell}:") and only.endswith(f"(in the cell of {p}, a scenario)")
    p = scenario(tmp_path, ("tick_hz: 200", "tick_hz: 2"), cell=cell)
    assert main(["check", str(p)]) == 2
    first, second = capsys.readouterr().err.splitlines()
    assert first.startswith(f"{p}:") and first.endswith("(read as a scenario)")
    assert second.startswith(f"{cell}:") and "(read as" not in second


def test_a_word_for_a_number_does_not_hide_the_checks_across_keys(tmp_path):
    """``tick_hz: "fifty"`` is listed, its default stands in, and the probabilities that do
    not sum to 1 and the speed above the belt's limit are listed with it."""
    p = scenario(tmp_path, ("tick_hz: 200", 'tick_hz: "fifty"'),
                 ("probability: 0.15", "probability: 0.2"),
                 ("horizontal_mm_s: 150", "horizontal_mm_s: 450"))
    got = problems(load_scenario, p)
    assert [e.key for e in got] == ["tick_hz", "parts.lens.poses", "present.horizontal_mm_s"]
    assert "expected a number, got string 'fifty'" in got[0].what
    assert "sum to 1, got 1.05" in got[1].what and "450 mm/s" in got[2].what
