"""The simulated vibratory plate: its physics, its accounting, its refusals,
smart feeding's choices, and a whole run on the plate cell — virtual time, fixed seeds."""

from __future__ import annotations

import statistics
from types import SimpleNamespace

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config import load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.jobs import JobState
from feeder_bt.core.plate_model import PlatePolicy, PlateSpec
from feeder_bt.policy.plate import PlateView, next_actions, view_of
from feeder_bt.sim.plate import PURGE_TRANSIT_S, make_plate_sim_hal

SCENARIO = "scenarios/plate_lenses.yaml"


def plate_hal(seed: int = 1, path: str = SCENARIO):
    scenario, cell = load_scenario(path)
    clock = SimClock()
    return make_plate_sim_hal(scenario, cell, clock, seed), clock


def finish(hal, clock, job, limit: float = 60.0):
    """Advance virtual time until the job ends."""
    t = start = clock.now()
    while not job.done and t < start + limit:
        t += 0.05
        clock.advance_to(t)
        hal.step(t)
    assert job.done, job
    return job


def census_total(world) -> int:
    return sum(world.census().values())


def xs(world) -> list[float]:
    return [r["x_mm"] for r in world.truth()]


def test_nothing_before_init_and_one_action_at_a_time():
    hal, clock = plate_hal()
    refused = hal.plate.dispense(1)
    assert refused.state is JobState.FAILED and "not initialised" in str(refused.error)
    finish(hal, clock, hal.plate.init())
    first = hal.plate.dispense(2)
    second = hal.plate.feed(1, 1)
    assert second.state is JobState.FAILED and "busy" in str(second.error)
    finish(hal, clock, first)
    assert first.ok and hal.plate.status().initialised and not hal.plate.status().busy


def test_dispense_feed_flip_purge_move_parts_and_count_every_one():
    hal, clock = plate_hal(seed=3)
    w = hal.world
    total = census_total(w)
    finish(hal, clock, hal.plate.init())
    for _ in range(3):
        finish(hal, clock, hal.plate.dispense(3))
    on_plate = len(w.on_horizontal)
    assert on_plate > 5 and len(w.hopper) == total - on_plate      # from the bulk only
    x_lo, x_hi = w.x_lo, w.x_hi
    assert max(xs(w)) <= x_lo + w.plate.dispense_band_mm            # the rear band
    before = statistics.mean(xs(w))
    finish(hal, clock, hal.plate.feed(1, 3))
    after = statistics.mean(xs(w))
    # three repetitions of 30 mm, less what the front wall stops
    assert 40.0 < after - before <= 3 * w.plate.feed_mm_per_rep * 1.5
    for _ in range(10):                                             # into the front wall
        finish(hal, clock, hal.plate.feed(1, 3))
    assert all(x_lo <= x <= x_hi for x in xs(w))
    assert statistics.mean(xs(w)) > x_hi - 60.0                     # gathered at the front
    poses = [r["pose"] for r in w.truth()]
    finish(hal, clock, hal.plate.flip(1))
    assert [r["pose"] for r in w.truth()] != poses or len(set(poses)) == 1
    assert census_total(w) == total and not w.problems
    finish(hal, clock, hal.plate.purge(10))
    assert not w.on_horizontal and len(w.returning) == on_plate
    t = clock.now() + PURGE_TRANSIT_S + 0.1    # they fall back into the bulk
    clock.advance_to(t)
    hal.step(t)
    assert len(w.hopper) == total and census_total(w) == total and w.lost() == 0


def test_a_flip_redraws_poses_from_their_probabilities():
    hal, clock = plate_hal(seed=5, path="scenarios/plate_squares.yaml")
    w = hal.world
    finish(hal, clock, hal.plate.init())
    for _ in range(6):
        finish(hal, clock, hal.plate.dispense(3))
    downs = []
    for _ in range(20):
        finish(hal, clock, hal.plate.flip(1))
        rows = w.truth()
        downs.append(sum(r["pose"] == "face_down" for r in rows) / len(rows))
    assert 0.3 < statistics.mean(downs) < 0.7                       # 50/50 in the YAML


def test_same_seed_same_plate_other_seed_other():
    def plate(seed):
        hal, clock = plate_hal(seed=seed)
        finish(hal, clock, hal.plate.init())
        finish(hal, clock, hal.plate.dispense(4))
        finish(hal, clock, hal.plate.flip(1, 1))
        return [(r["id"], round(r["x_mm"], 6), r["pose"]) for r in hal.world.truth()]
    assert plate(7) == plate(7)
    assert plate(7) != plate(8)


def test_a_plate_cell_has_no_belt_to_move():
    hal, _ = plate_hal()
    assert hal.conveyors["horizontal"].move(100.0, 100.0).state is JobState.FAILED
    assert hal.conveyors["horizontal"].stop().ok


# ------------------------------------------------------------------ smart feeding

POLICY = PlatePolicy()


def test_smart_feeding_rules():
    def acts(**kw):
        view = PlateView(**{"pickable": 0, "unpickable": 0, "rejected": 0, "centre": 0.5,
                            "parts": 10.0, **kw})
        return [a for a, _ in next_actions(view, POLICY)[0]]
    assert acts(parts=2.0) == ["dispense"]
    assert acts(parts=40.0, rejected=5) == ["purge"]
    assert acts(unpickable=6, pickable=2, centre=0.1) == ["feed_forward"]
    assert acts(unpickable=6, pickable=2, centre=0.95) == ["feed_backward"]
    assert acts(unpickable=6, pickable=2) == ["flip"]
    fixed = PlatePolicy(policy="fixed")
    assert [a for a, _ in next_actions(PlateView(0, 0, 0, None, 0.0), fixed)[0]] == [
        "dispense", "feed_forward", "flip"]


def test_the_periodic_fixed_cycle_runs_in_full_on_every_nth_empty_look():
    """The fixed baseline searched over periods: dispense, feed and flip on the first and
    every Nth look that found nothing new after it, else flip only."""
    every3 = PlatePolicy(policy="fixed", fixed_every=3)
    plans = [[a for a, _ in next_actions(PlateView(0, 0, 0, None, 0.0), every3, n)[0]]
             for n in range(1, 8)]
    full, flip = ["dispense", "feed_forward", "flip"], ["flip"]
    assert plans == [full, flip, flip, full, flip, flip, full]
    every1 = PlatePolicy(policy="fixed")
    assert all(next_actions(PlateView(0, 0, 0, None, 0.0), every1, n)[0][0][0] == "dispense"
               for n in range(1, 5))


def test_the_view_is_the_recipe_result_only():
    plate = PlateSpec(origin_mm=(100.0, 0.0), size_mm=(400.0, 300.0))

    def det(x, pickable=True, area=2000.0):
        return SimpleNamespace(x_mm=x, pickable=pickable, features={"area_mm2": area})
    result = SimpleNamespace(parts=[det(120.0), det(140.0, False)],
                             rejected=[det(130.0, False, 6000.0)])
    v = view_of(result, plate, part_area=2000.0)
    assert (v.pickable, v.unpickable, v.rejected) == (1, 1, 1)
    assert v.parts == pytest.approx(5.0) and v.centre == pytest.approx(0.075)


# ------------------------------------------------------------------ whole runs

@pytest.fixture(scope="module")
def plate_run():
    return run_job(RunOptions(scenario=SCENARIO, duration=600.0, fast=True, seed=1,
                              view="none"))


def test_the_plate_cell_feeds_and_loses_nothing(plate_run):
    r = plate_run
    assert r["state"] == "STOPPED" and r["fault"] is None
    assert r["parts"]["lost"] == 0 and r["parts"]["duplicated"] == 0
    assert r["parts"]["retrieved"]["lens"] > 150                    # > 15/min over 10 min
    assert r["world"]["placed"]["lens"] == r["parts"]["retrieved"]["lens"]
    assert sum(r["world"]["census"].values()) == 300


def test_plate_runs_repeat_by_seed(plate_run):
    again = run_job(RunOptions(scenario=SCENARIO, duration=600.0, fast=True, seed=1,
                               view="none"))
    assert again["parts"] == plate_run["parts"]


def test_plate_actions_are_in_the_report(plate_run):
    plate = plate_run["plate"]
    assert plate["decisions"] > 0 and plate["dispense"] > 0
    assert sum(v for k, v in plate.items() if k != "decisions") >= plate["decisions"]


def test_squares_that_land_face_down_are_flipped_not_misplaced():
    r = run_job(RunOptions(scenario="scenarios/plate_squares.yaml", duration=300.0, fast=True,
                           seed=2, view="none"))
    assert r["parts"]["lost"] == 0 and r["parts"]["retrieved"]["square"] > 50
    assert r["parts"]["misoriented"] == 0            # face-down squares are never picked
    assert r["parts"]["located_unpickable"] > 0      # the recipe saw them face down
    assert r["plate"]["flip"] > 0                    # and smart feeding flipped them


def test_a_part_the_plate_drops_is_counted_lost_and_named():
    """The accounting can fail: a part that leaves the plate for nowhere is found by the
    audit, by id, and a part that is on the plate twice is a duplicate."""
    hal, clock = plate_hal(seed=3)
    w = hal.world
    finish(hal, clock, hal.plate.init())
    finish(hal, clock, hal.plate.dispense(3))
    gone, _ = w.on_horizontal.popitem()     # broken physics: a part falls off the world
    twice = next(iter(w.on_horizontal))
    w.hopper.append(twice)                  # and one is on the plate and in the bulk
    w.audit()
    assert w.lost() == 1 and w.duplicated() == 1
    named = {(p["kind"], p["id"]) for p in w.problems}
    assert ("lost", gone) in named and ("duplicated", twice) in named
