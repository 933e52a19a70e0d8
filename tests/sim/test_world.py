"""The simulated world on its own: kinematics, part flow, accounting, grips judged by truth."""

from __future__ import annotations

import math

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import EnvelopeError, MissedGrab
from feeder_bt.hal.interfaces import PickTarget, Pose
from feeder_bt.robot.model import RobotModel
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.world import World


@pytest.fixture(scope="module")
def lenses():
    return load_scenario("scenarios/lenses.yaml")


def make_world(lenses, seed=7):
    scenario, cell = lenses
    clock = SimClock()
    return World(scenario, cell, clock, seed), clock


def run_belts(world, clock, seconds, dt, h=150.0, i=60.0):
    world.horizontal.jog(0.0, h)
    world.incline.jog(0.0, i)
    t = 0.0
    while t < seconds - 1e-9:
        t = min(seconds, t + dt)
        clock.advance_to(t)
        world.step(t)


def test_axis_jog_and_move_are_exact():
    a = Axis(accel_mm_s2=1000.0, max_mm_s=400.0)
    t_ramp = a.jog(0.0, 100.0)
    assert t_ramp == pytest.approx(0.1)
    assert a.pos(0.1) == pytest.approx(5.0)          # ½ a t²
    assert a.pos(1.1) == pytest.approx(105.0)
    assert a.time_at(105.0, 0.0) == pytest.approx(1.1)
    end = a.move(2.0, 240.0, 100.0)                   # from 100 mm/s, a move of 240 mm
    assert a.pos(end) - a.pos(2.0) == pytest.approx(240.0)
    assert a.vel(end) == pytest.approx(0.0)
    assert a.time_at(a.pos(end) + 1.0, end) is None   # never gets further


def test_standard_cycle_is_half_a_second_and_scales_with_speed(lenses):
    model = RobotModel(lenses[1].robot)
    assert model.standard_cycle(100.0) == pytest.approx(0.5, abs=0.01)
    assert model.standard_cycle(50.0) == pytest.approx(2 * model.standard_cycle(100.0))


def test_every_part_is_accounted_for_while_parts_flow(lenses):
    world, clock = make_world(lenses)
    run_belts(world, clock, 240.0, 0.05)
    census = world.census()
    assert sum(census.values()) == world.total == 300
    assert world.counts["released"] > 100
    assert world.counts["recirculated"] > 20           # unpicked parts go round
    assert census["horizontal"] > 0 and census["return"] + census["hopper"] > 0
    assert world.lost() == 0


def test_events_do_not_depend_on_how_often_the_world_is_stepped(lenses):
    fine, c1 = make_world(lenses, seed=3)
    coarse, c2 = make_world(lenses, seed=3)
    run_belts(fine, c1, 90.0, 0.02)
    run_belts(coarse, c2, 90.0, 1.7)
    assert fine.census() == coarse.census()
    assert fine.counts == coarse.counts
    a, b = fine.truth(90.0), coarse.truth(90.0)
    assert [(r["id"], round(r["x_mm"], 6), r["pose"]) for r in a] == \
           [(r["id"], round(r["x_mm"], 6), r["pose"]) for r in b]


def test_release_rate_grows_with_incline_speed(lenses):
    slow, c1 = make_world(lenses, seed=5)
    fast, c2 = make_world(lenses, seed=5)
    run_belts(slow, c1, 120.0, 0.1, i=30.0)
    run_belts(fast, c2, 120.0, 0.1, i=90.0)
    assert fast.counts["released"] > 2 * slow.counts["released"]


def _target(world, row, t, dx=0.0):
    return PickTarget(part_id=row["id"], x_mm=row["x_mm"] + dx, y_mm=row["y_mm"],
                      angle_deg=row["angle_deg"], latch=world.robot_track_count(t), tracking=True)


def test_grip_is_judged_against_the_truth(lenses):
    world, clock = make_world(lenses, seed=11)
    run_belts(world, clock, 60.0, 0.05)
    t = clock.now()
    rows = [r for r in world.truth(t) if r["pickable"] and r["singulated"]]
    assert rows, "the belt should carry singulated parts after a minute"
    row = rows[0]
    with pytest.raises(MissedGrab):                     # 10 mm off: nothing under the cup
        world.grip(_target(world, row, t, dx=10.0), t)
    result = world.grip(_target(world, row, t), t)
    assert result.part_id == row["id"]
    assert world.parts[row["id"]].where == "gripper"
    world.release(Pose(1330.0, -120.0), t)
    assert world.parts[row["id"]].where == "placed"
    assert world.placed_by_type["lens"] == 1
    assert world.lost() == 0


def test_unpickable_pose_is_refused(lenses):
    world, clock = make_world(lenses, seed=2)
    run_belts(world, clock, 120.0, 0.05)
    t = clock.now()
    rows = [r for r in world.truth(t) if not r["pickable"]]
    assert rows, "about 15 % of lenses land on edge"
    with pytest.raises(MissedGrab, match="on_edge"):
        world.grip(_target(world, rows[0], t), t)


def test_tracking_pick_waits_for_parts_upstream_and_refuses_gone_ones(lenses):
    world, clock = make_world(lenses, seed=4)
    run_belts(world, clock, 40.0, 0.05)
    t = clock.now()
    rows = sorted(world.truth(t), key=lambda r: r["x_mm"])
    upstream = rows[0]
    t_arr, t_grip = world.plan_pick(_target(world, upstream, t), t)
    x_at_grip = upstream["x_mm"] + (world.horizontal.pos(t_grip) - world.horizontal.pos(t))
    assert world.robot_model.reachable(x_at_grip, upstream["y_mm"])
    assert t_grip > t_arr > t
    gone = dict(upstream, x_mm=world.h_len + 50.0)
    with pytest.raises(EnvelopeError):
        world.plan_pick(_target(world, gone, t), t)
    assert math.isfinite(t_grip)
