"""The new adjuster and pick policy, the robot bound, the original CWRU feeder."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from py_trees.common import Status

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.behaviours.locate import QueueEmpty
from feeder_bt.behaviours.policies import POLICIES, ShortestCycle
from feeder_bt.config import load_scenario
from feeder_bt.hal.interfaces import Pose
from feeder_bt.policy.adjusters import AdjusterParamError, AdjustInputs, make_adjuster
from feeder_bt.robot.scara import world_arm
from feeder_bt.sim import devices
from feeder_bt.trees import retrieve
from tests.support.treeutil import make_ctx, part, pending, tick

ROOT = Path(__file__).resolve().parents[2]


def inputs(queue: int, h: float = 150.0, incline: float = 40.0) -> AdjustInputs:
    return AdjustInputs(t=0.0, queue_len=queue, horizontal_mm_s=h, incline_pct=incline,
                        robot_speed_pct=100.0, retrieved=0, located=0, recirculated=0, missed=0)


# ---------------------------------------------------------------- supply_queue adjuster


def test_supply_queue_raises_supply_when_the_queue_is_short():
    adj = make_adjuster("supply_queue", {})
    out = adj.update(inputs(queue=4))
    assert out.incline_pct == pytest.approx(44.0)          # 40 + 1.0 * (8 - 4)
    assert out.horizontal_mm_s == pytest.approx(160.0)     # 150 + 0.2 * (200 - 150)
    assert out.robot_speed_pct == 100.0


def test_supply_queue_cuts_supply_within_limits_when_parts_pile_up():
    adj = make_adjuster("supply_queue", {"gain_pct": 2.0})
    assert adj.update(inputs(queue=30)).incline_pct == 20.0          # 40 - 44, clamped
    assert adj.update(inputs(queue=0, incline=119.0)).incline_pct == 120.0
    held = adj.update(inputs(queue=8, h=200.0, incline=55.0))
    assert (held.incline_pct, held.horizontal_mm_s) == (55.0, 200.0)


@pytest.mark.parametrize("params, key", [
    ({"min_incline_pct": 90, "max_incline_pct": 80}, "min_incline_pct"),
    ({"pull": 1.5}, "pull"),
    ({"horizontal_mm_s": 400}, "horizontal_mm_s"),
])
def test_supply_queue_rejects_bad_params(params, key):
    with pytest.raises(AdjusterParamError) as e:
        make_adjuster("supply_queue", params)
    assert e.value.key == key


# ---------------------------------------------------------------- shortest_cycle policy


def test_shortest_cycle_is_registered():
    assert POLICIES["shortest_cycle"] is ShortestCycle


@pytest.mark.parametrize("policy, expected", [("fifo", 0), ("shortest_cycle", 1)])
def test_shortest_cycle_picks_the_part_nearest_the_robot(policy, expected):
    ctx = make_ctx(retrieve={"policy": policy})
    ctx.hal.robot_position.at = Pose(1330.0, -120.0)       # just placed a lens
    root = retrieve.build(ctx)
    far = part(1000.0, 500.0, located_at=1.0)               # first in, across the belt
    near = part(1000.0, 100.0, located_at=2.0)              # later, near the place pose
    ctx.queue.put(far)
    ctx.queue.put(near)
    tick(root, ctx)
    assert pending(ctx.hal, "robot", "pick").args[0].part_id == (far, near)[expected].id


def test_shortest_cycle_cost_is_the_robot_model_time():
    ctx = make_ctx(retrieve={"policy": "shortest_cycle", "tracking": False})
    ctx.hal.robot_position.at = Pose(1330.0, -120.0)
    pol = ShortestCycle(ctx)
    p = part(1100.0, 100.0)
    r = ctx.cell.robot

    def arch(d: float) -> float:           # trapezoid, independently: 4000 mm/s, 21000 mm/s²
        d += r.approach_mm
        ramp = r.v_max_mm_s ** 2 / r.a_max_mm_s2
        if d <= ramp:
            return 2 * math.sqrt(d / r.a_max_mm_s2)
        return 2 * r.v_max_mm_s / r.a_max_mm_s2 + (d - ramp) / r.v_max_mm_s

    d = math.hypot(1330.0 - 1100.0, -120.0 - 100.0)
    expected = arch(d) + r.grip_s + arch(d) + r.release_s
    assert pol.cost(p, lambda q: q.x_mm, 150.0) == pytest.approx(expected, abs=1e-9)


def test_shortest_cycle_skips_a_part_that_passes_too_far_before_the_grip():
    ctx = make_ctx(retrieve={"policy": "shortest_cycle"})
    ctx.hal.robot_position.at = Pose(1330.0, -120.0)
    pol = ShortestCycle(ctx)
    # 1180 mm now; at 300 mm/s it is past too_far (1190) long before any grip
    assert pol.cost(part(1180.0, 100.0), lambda q: q.x_mm, 300.0) == math.inf
    assert math.isfinite(pol.cost(part(900.0, 100.0), lambda q: q.x_mm, 300.0))


# ---------------------------------------------------------------- incremental serial order


def test_incremental_look_waits_until_the_taken_part_is_dealt_with():
    ctx = make_ctx(present={"mode": "incremental"})
    leaf = QueueEmpty("queue empty?", ctx)
    leaf.setup()
    ctx.stats.count("located")             # found one; the retriever took it from the queue
    assert tick(leaf, ctx) is Status.RUNNING
    ctx.stats.count("missed")              # the pick ended (here: a miss)
    assert tick(leaf, ctx) is Status.SUCCESS


# ---------------------------------------------------------------- report and whole runs


def test_robot_bound_is_sixty_over_the_shortest_cycle():
    """The corner bound, priced with the world's arm (a SCARA, feeder_bt.robot.scara): 60 over
    the cycle to the window's best point, and no point of a coarse grid of the window
    (searched here, apart from the model's own search) gives a shorter cycle."""
    r = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "lenses.yaml"), duration=20.0,
                           fast=True, seed=1, view="none"))
    sc, cell = load_scenario(ROOT / "scenarios" / "lenses.yaml")
    rb = cell.robot
    arm = world_arm(rb)
    place = (sc.parts["lens"].place.x, sc.parts["lens"].place.y)
    fixed = rb.track_settle_s + rb.grip_s + rb.release_s
    cycle = r["robot_bound_cycle_s"]
    assert r["robot_bound_ppm"] == pytest.approx(60.0 / cycle, abs=0.01)   # cycle: 4 digits
    grid = [(x, y) for x in np.linspace(0, sc.retrieve.too_far_mm, 60)
            for y in np.linspace(28.0, 582.0, 30) if arm.reachable(x, y)]
    best = min(2 * arm.move_time(place, p, 100.0) + fixed for p in grid)
    assert 0.97 * best <= cycle <= best + 1e-4            # cycle: rounded to 4 digits
    assert "parts_per_minute" in r and "tick" in r            # existing keys kept


def test_original_feeder_feeds_slowly_in_series(monkeypatch):
    moves: list[tuple[str, float]] = []
    original = devices.SimConveyor.move

    def move(self, distance, speed):
        moves.append((self.name, distance))
        return original(self, distance, speed)

    monkeypatch.setattr(devices.SimConveyor, "move", move)
    r = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "original_cwru_lenses.yaml"),
                           duration=240.0, fast=True, seed=1, view="none"))
    assert r["state"] == "STOPPED" and r["parts"]["lost"] == 0
    assert 5.0 <= r["parts_per_minute"] <= 20.0
    assert r["parts"]["too_far"] == 0
    assert ("horizontal", 75.0) in moves and ("horizontal", 880.0) in moves   # small, big
    assert ("incline", 400.0) in moves
