"""A plate cell's twin, small: a plant whose dispense, flip and action times are not the
cell file's, its log, the twin, a prediction at another setting (``benchmarks/
twin_bench.py --plate`` does the full round trip)."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.config.world import load_world, world_notes
from feeder_bt.tuning.roundtrip import Runner, Setting, draw_plants, nominal_figures
from feeder_bt.tuning.twin import RunLog, fit_twin
from feeder_bt.tuning.twin_plate import plate_counts

ROOT = Path(__file__).resolve().parents[2]
PLATE = str(ROOT / "scenarios/plate_lenses.yaml")
FEWER_REPS = Setting("dispense x1, flip x2, feed x1", PLATE,
                     {"present": {"plate": {"dispense_reps": 1, "flip_reps": 2,
                                            "feed_reps": 1}}})


@pytest.fixture(scope="module")
def round_trip(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("twin_plate")
    _, cell = load_scenario(PLATE)
    plant = nominal_figures(cell)
    plant["plate.dispense_per_rep"] *= 1.4         # a plate that drops more than believed
    plant["plate.rep_s"] *= 0.8                    # moves faster
    plant["plate.settle_s"] *= 1.3                 # and settles slower
    plant["plate.flip_scatter_mm"] *= 0.6
    # a plate run is quick: the 600 s log the benchmark's fit reads, two short rounds
    runner = Runner(duration=600.0, tmp=tmp)
    world = runner.world(plant)
    db = str(tmp / "plant.db")
    runner.ppm(Setting("as shipped", PLATE), world, (1,), db=db)
    twin = fit_twin([db], cell, rounds=2, seeds=(101,))
    out = tmp / "twin.yaml"
    twin.write(out)
    return cell, plant, twin, out, runner, world


def test_the_plate_fit_finds_the_plant(round_trip) -> None:
    cell, plant, twin, _, _, _ = round_trip
    e = twin.estimates
    # the action times straight from the logged actions
    for k in ("plate.rep_s", "plate.settle_s"):
        assert e[k].fixed and e[k].value == pytest.approx(plant[k], abs=0.01)
    d = e["plate.dispense_per_rep"]
    assert d.fixed and abs(d.value - plant["plate.dispense_per_rep"]) < 2.5 * d.sd
    assert d.value > cell.plate.dispense_per_rep + d.sd      # away from the cell file's
    s = e["plate.flip_scatter_mm"]
    assert s.fixed and s.value < cell.plate.flip_scatter_mm


def test_the_plate_twin_is_a_world_file_that_says_what_fixed_it(round_trip) -> None:
    cell, _, twin, out, _, _ = round_trip
    w = load_world(out, cell)
    assert w.plate.rep_s == pytest.approx(twin.estimates["plate.rep_s"].value, rel=1e-5)
    notes = world_notes(out)
    assert "timed plate actions" in notes["fitted"]["plate.rep_s"]["fixed_by"]
    assert "dispense repetition" in notes["fitted"]["plate.dispense_per_rep"]["fixed_by"]
    assert "plate.flip_prob" in notes["not_fixed"]
    assert "sim.belt_mu_static" not in notes["not_fixed"]      # a plate has no belt


def test_the_plate_twin_predicts_another_setting_better_than_the_defaults(round_trip) -> None:
    """Fewer repetitions a dispense and a feed: the same seeds for the plant, the twin and
    the defaults (common random numbers); the benchmark draws them apart."""
    _, _, _, out, runner, world = round_trip
    seeds = (21,)
    truth = runner.ppm(FEWER_REPS, world, seeds)
    twin = runner.ppm(FEWER_REPS, str(out), seeds)
    defaults = runner.ppm(FEWER_REPS, None, seeds)
    assert abs(twin - truth) / truth < 0.06
    assert abs(twin - truth) < abs(defaults - truth) / 2


def test_plate_counts_read_only_the_log() -> None:
    """What a plate fit matches, from the events alone: parts picked per dispense
    repetition, the blobs after a flip, how far a feed moved the blobs."""
    run = RunLog("x.db", 1, {}, t_end=100.0)
    run.frames = [(1.0, {"new": 0, "parts": 2, "pickable": 0, "x_mm": 200.0,
                         "rejected": [["no class", 5000, 1, 2]]}),
                  (3.0, {"new": 1, "parts": 2, "pickable": 1, "x_mm": 260.0,
                         "rejected": [["no class", 5000, 1, 2]]}),
                  (6.0, {"new": 2, "parts": 3, "pickable": 2, "x_mm": 250.0,
                         "rejected": []})]
    run.plate = [(2.9, {"action": "feed_forward", "reps": 2, "dt": 1.0}),
                 (5.9, {"action": "flip", "reps": 1, "dt": 0.6}),
                 (7.0, {"action": "dispense", "reps": 2, "dt": 0.9})]
    run.picks = [(3.5, {"outcome": "held"}), (6.5, {"outcome": "held"}),
                 (6.8, {"outcome": "missed_grab"})]
    c = plate_counts(run)
    assert (c["held"], c["dispense_reps"]) == (2, 2)
    assert (c["feeds"], c["feed_reps"], c["feed_shift"]) == (1, 2, pytest.approx(60.0))
    assert (c["flips"], c["after_blobs"], c["after_rejected"]) == (1, 3, 0)


def test_plate_plants_move_the_plate_figures() -> None:
    _, cell = load_scenario(PLATE)
    nominal = nominal_figures(cell)
    (plant,) = draw_plants(cell, 1, 7)
    assert set(plant) == set(nominal)
    assert all(plant[k] != nominal[k] for k in plant)
    assert 0.0 < plant["plate.flip_prob"] <= 1.0
