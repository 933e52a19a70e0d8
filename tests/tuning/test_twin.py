"""A twin's round trip, small: a plant unknown to the fit, its log, the twin, a prediction
at another setting (benchmarks/twin_bench.py does the full one)."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario
from feeder_bt.config.world import load_world, world_notes
from feeder_bt.tuning.roundtrip import Runner, Setting, nominal_figures
from feeder_bt.tuning.twin import fit_twin

ROOT = Path(__file__).resolve().parents[2]
LENSES = str(ROOT / "scenarios/lenses.yaml")
LOW_LIFT = Setting("fixed belt 150 mm/s, lift 25 %", LENSES,
                   {"adjust": {"algorithm": "none"},
                    "present": {"horizontal_mm_s": 150, "incline_pct": 25}})


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("twin")
    _, cell = load_scenario(LENSES)
    plant = nominal_figures(cell)
    plant["hopper.release_per_mm"] *= 0.75            # a hopper slower than believed
    plant["sim.arm_j1_deg_s"] *= 1.12                 # and an arm faster
    runner = Runner(duration=300.0, tmp=tmp)
    world = runner.world(plant)
    db = str(tmp / "plant.db")
    runner.ppm(Setting("as shipped", LENSES), world, (1,), db=db)
    twin = fit_twin([db], cell, rounds=2, seeds=(101,))
    out = tmp / "twin.yaml"
    twin.write(out)
    return cell, plant, twin, out, runner, world


def test_the_fit_finds_the_plant_not_the_cell_file(round_trip) -> None:
    cell, plant, twin, _, _, _ = round_trip
    e = twin.estimates
    r = e["hopper.release_per_mm"]
    assert r.fixed and abs(r.value - plant["hopper.release_per_mm"]) < 2.5 * r.sd
    assert abs(r.value - plant["hopper.release_per_mm"]) \
        < abs(cell.hopper.release_per_mm - plant["hopper.release_per_mm"]) / 2
    j1 = e["arm_j1_deg_s"]
    assert j1.fixed and j1.value == pytest.approx(plant["sim.arm_j1_deg_s"], rel=0.03)
    cv = e["sim.robot_time_cv"]        # the world's per-move noise, the cell file's 2 %
    assert cv.fixed and cv.value == pytest.approx(cell.sim.robot_time_cv, rel=0.15)


def test_the_twin_is_a_world_file_that_says_what_fixed_it(round_trip) -> None:
    cell, _, twin, out, _, _ = round_trip
    w = load_world(out, cell)          # validates as any world file
    assert w.hopper.release_per_mm == pytest.approx(twin.estimates["hopper.release_per_mm"].value,
                                                    rel=1e-5)
    notes = world_notes(out)
    assert "parts located per mm" in notes["fitted"]["hopper.release_per_mm"]["fixed_by"]
    assert notes["fitted"]["hopper.release_per_mm"]["sd"] > 0
    # what the log cannot fix is said, with why
    assert "sim.belt_mu_static" in notes["not_fixed"]
    assert all(isinstance(why, str) and why for why in notes["not_fixed"].values())


def test_the_twin_predicts_another_setting_better_than_the_defaults(round_trip) -> None:
    """A low lift, where the hopper sets the pace. The same seeds for the plant, the twin
    and the defaults (common random numbers) keep a short run's scatter out of the
    comparison; the benchmark draws them apart."""
    _, _, _, out, runner, world = round_trip
    seeds = (21, 22)
    truth = runner.ppm(LOW_LIFT, world, seeds)
    twin = runner.ppm(LOW_LIFT, str(out), seeds)
    defaults = runner.ppm(LOW_LIFT, None, seeds)
    assert abs(twin - truth) / truth < 0.06
    assert abs(defaults - truth) / truth > 0.15          # the cell file's hopper is wrong
    assert abs(twin - truth) < abs(defaults - truth) / 3


def test_bad_logs_are_one_line_exit_2(tmp_path: Path, capsys) -> None:
    rc = main(["twin", "fit", str(tmp_path / "none.db"), "--cell", str(ROOT / "cells/sim.yaml"),
               "--out", str(tmp_path / "t.yaml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "none.db" in err[0]
    (tmp_path / "x.db").write_text("not sqlite")
    rc = main(["twin", "fit", str(tmp_path / "x.db"), "--cell", str(ROOT / "cells/sim.yaml"),
               "--out", str(tmp_path / "t.yaml")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "x.db" in err[0]
    assert not (tmp_path / "t.yaml").exists()
    assert yaml.safe_load("a: 1")          # the module's YAML stays importable here


def test_tune_runs_its_trials_on_a_world() -> None:
    """`feeder tune --world`: every trial on the world's truth, in a study of its own."""
    from feeder_bt.tuning.objective import Job, evaluate
    from feeder_bt.tuning.search import TuneConfig, study_name
    plant = str(ROOT / "examples/plant_b.yaml")
    on_cell = evaluate(Job(LENSES, {}, 1, 120.0))
    on_plant = evaluate(Job(LENSES, {}, 1, 120.0, world=plant))
    assert on_plant["ppm"] != on_cell["ppm"]
    assert study_name(TuneConfig(LENSES, world=plant)) != study_name(TuneConfig(LENSES))


def test_counts_read_only_the_log() -> None:
    """The counts a fit matches, from a log's events alone: the incline's travel from its
    logged speed changes, parts located set against it."""
    from feeder_bt.tuning.twin import RunLog, counts
    run = RunLog("x.db", 1, {}, t_end=100.0)
    run.speeds = [(0.0, {"incline_mm_s": 50.0}), (40.0, {"incline_mm_s": 100.0})]
    run.frames = [(10.0, {"new": 2, "parts": 2, "rejected": [["no class", 4000, 1, 2]]}),
                  (60.0, {"new": 3, "parts": 4, "rejected": [["touches border", 900, 1, 2]]})]
    run.picks = [(20.0, {"outcome": "held"}), (30.0, {"outcome": "missed_grab"})]
    c = counts(run)
    # the first part came 10 s in: the travel that brought the parts ends 10 s early
    assert c["travel"] == pytest.approx(40 * 50 + 50 * 100)
    assert (c["located"], c["no_class"], c["blobs"]) == (5, 1, 8)
    assert (c["picks"], c["missed"]) == (2, 1)
    assert c["early"] == 2 and c["early_travel"] == pytest.approx(30 * 50)
