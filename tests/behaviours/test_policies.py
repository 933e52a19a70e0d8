"""Pick policies priced by the robot model, and the loop that starts a cycle in the tick
the last one ended."""

from __future__ import annotations

import math

import numpy as np
import py_trees
import pytest
from py_trees.common import Status

from feeder_bt.behaviours.policies import POLICIES, Lookahead, ShortestCycle
from feeder_bt.behaviours.retrieve import NextPart
from feeder_bt.config.loader import RETRIEVE_POLICIES
from feeder_bt.hal.interfaces import Pose
from feeder_bt.robot.fit import robot_fit
from feeder_bt.robot.model import RobotModel
from feeder_bt.trees import retrieve
from feeder_bt.trees.build import Loop
from tests.support.treeutil import bb_set, finish, make_ctx, part, pending, tick

PLACE = Pose(1330.0, -120.0)
BELT = 250.0


def x_now(p):
    return p.x_mm


def policies(ctx):
    out = []
    for cls in (ShortestCycle, Lookahead):
        pol = cls(ctx)
        pol.belt_mm_s = BELT
        out.append(pol)
    return out


def test_every_policy_the_loader_accepts_is_registered():
    assert set(RETRIEVE_POLICIES) == set(POLICIES)


def test_vector_model_agrees_with_the_scalar_one():
    ctx = make_ctx()
    model = RobotModel(ctx.cell.robot)
    d = np.array([0.0, 5.0, 120.0, 400.0, 737.0, 2000.0])
    for pct in (100.0, 37.5, 5.0):
        assert model.arch_times(d, pct) == pytest.approx([model.arch_time(v, pct) for v in d],
                                                         abs=1e-12)
    xs, ys = np.array([1370.0, 1300.0, 800.0, 1000.0]), np.array([305.0, 100.0, 305.0, 600.0])
    assert list(model.reachable_mask(xs, ys)) == [model.reachable(x, y)
                                                  for x, y in zip(xs, ys, strict=True)]


def test_tracking_cost_is_the_intercept_then_the_place():
    """The part moves while the robot travels: the cost is the robot model's time to the
    point where the two meet, the settle and grip, and the move to the place pose."""
    ctx = make_ctx(retrieve={"policy": "shortest_cycle"})
    ctx.hal.robot_position.at = PLACE
    pol, _ = policies(ctx)
    model, r = pol.model, ctx.cell.robot
    p = part(1000.0, 150.0)
    t = 0.3
    for _ in range(50):                      # solve the intercept independently
        t = model.arch_time(math.dist((PLACE.x, PLACE.y), (1000.0 + BELT * t, 150.0)), 100.0)
    x_grip = 1000.0 + BELT * (t + r.track_settle_s + r.grip_s)
    expected = (t + r.track_settle_s + r.grip_s
                + model.arch_time(math.dist((x_grip, 150.0), (PLACE.x, PLACE.y)), 100.0)
                + r.release_s)
    assert pol.cost(p, x_now, BELT) == pytest.approx(expected, abs=1e-4)  # 4 iterations


def test_lookahead_takes_the_part_about_to_leave_and_leaves_the_one_still_coming():
    """Greedy takes A, the cheaper part now; but A is still coming down the belt towards the
    place pose and will be cheaper a cycle later, while B is about to pass out of reach.
    Two picks cost less as B then A."""
    ctx = make_ctx(retrieve={"policy": "lookahead"})
    ctx.hal.robot_position.at = PLACE
    greedy, ahead = policies(ctx)
    a, b = part(860.0, 40.0), part(1040.0, 300.0)
    assert greedy.cost(a, x_now, BELT) < greedy.cost(b, x_now, BELT)
    assert greedy.choose([a, b], x_now) is a
    assert ahead.choose([a, b], x_now) is b


def test_lookahead_falls_back_like_shortest_cycle():
    ctx = make_ctx(retrieve={"policy": "lookahead"})
    ctx.hal.robot_position.at = PLACE
    _, ahead = policies(ctx)
    assert ahead.choose([], x_now) is None
    only = part(1000.0, 200.0)
    assert ahead.choose([only], x_now) is only
    # nothing can be caught: like shortest_cycle, the one furthest down the belt
    gone = [part(1185.0, 100.0), part(1189.0, 500.0)]
    assert ahead.choose(gone, x_now) is gone[1]


class _Counts(py_trees.behaviour.Behaviour):
    def __init__(self, status: Status) -> None:
        super().__init__("counts")
        self.result, self.updates = status, 0

    def update(self) -> Status:
        self.updates += 1
        return self.result


@pytest.mark.parametrize("status, updates, shown", [
    (Status.SUCCESS, 2, Status.RUNNING),      # the next cycle starts in the same tick
    (Status.RUNNING, 1, Status.RUNNING),
    (Status.FAILURE, 1, Status.FAILURE),
])
def test_loop_starts_the_next_cycle_in_the_same_tick(status, updates, shown):
    leaf = _Counts(status)
    loop = Loop("loop", leaf)
    loop.tick_once()
    assert (leaf.updates, loop.status) == (updates, shown)


def test_the_next_pick_is_sent_in_the_tick_the_place_ends():
    ctx = make_ctx()
    branch = Loop("retrieve loop", retrieve.build(ctx))
    for p in (part(1000.0, 100.0), part(1000.0, 400.0)):
        ctx.queue.put(p)
    tick(branch, ctx)
    first = finish(ctx.hal, "robot", "pick")
    tick(branch, ctx)
    finish(ctx.hal, "robot", "place")
    tick(branch, ctx)                        # one tick: the place is seen, the pick sent
    assert pending(ctx.hal, "robot", "pick") is not first


@pytest.mark.parametrize("policy", ["fifo", "earliest_deadline", "shortest_cycle",
                                    "lookahead"])
@pytest.mark.parametrize("measured", [True, False])
def test_every_policy_drops_only_what_no_pick_can_catch(policy, measured):
    """Every policy prices reach with the learnt model: once the fit has measured a move, a
    part 40 mm short of too_far at 150 mm/s (0.27 s of belt, more than settle + grip + the
    shortest move) is kept and picked. Before any measured move ``reach_time_s`` (0.35 s:
    52.5 mm of belt) is the prior, and the part is dropped, whatever the policy."""
    ctx = make_ctx(retrieve={"policy": policy})
    if measured:
        robot_fit(ctx).samples["pick"] += 1
    ctx.hal.robot_position.at = Pose(1180.0, 40.0)       # right above the part
    root = retrieve.build(ctx)
    close = part(ctx.scenario.retrieve.too_far_mm - 40.0, 40.0)
    ctx.queue.put(close)
    tick(root, ctx)
    assert ctx.stats.counts["too_far"] == (0 if measured else 1)
    assert bool(ctx.hal.pending("robot", "pick")) is measured


@pytest.mark.parametrize("policy, first", [("fifo", 1), ("earliest_deadline", 1)])
def test_fifo_and_edf_keep_their_order_but_skip_what_cannot_be_caught(policy, first):
    """FIFO takes the first part in the queue that can still be caught, EDF the one
    furthest down the belt of those: a part the arm would reach only past too_far (here
    one at the belt's far side, 20 mm short of too_far, the arm at the other side) is
    passed over by the same priced check shortest_cycle makes, instead of sent for."""
    ctx = make_ctx(retrieve={"policy": policy})
    robot_fit(ctx).samples["pick"] += 1
    ctx.hal.robot_position.at = PLACE
    pol = POLICIES[policy](ctx)
    pol.belt_mm_s = BELT
    too_far = ctx.scenario.retrieve.too_far_mm
    late, ok, later = part(too_far - 20.0, 500.0), part(1000.0, 200.0), part(900.0, 150.0)
    assert not math.isfinite(pol.cost(late, x_now, BELT))
    assert math.isfinite(pol.cost(ok, x_now, BELT))
    parts = [late, ok, later]
    assert pol.choose(parts, x_now) is parts[first]
    # nothing can be caught: the policy's own first choice, as before the pricing
    assert pol.choose([late], x_now) is late


def test_pricing_follows_the_robot_speed_on_the_blackboard():
    """The operator or the adjuster may slow the robot: picks are priced at that speed."""
    ctx = make_ctx(retrieve={"policy": "shortest_cycle", "tracking": False})
    ctx.hal.robot_position.at = PLACE
    root = retrieve.build(ctx)
    p = part(1100.0, 100.0)
    full = ShortestCycle(ctx).cost(p, x_now, 0.0)
    bb_set("/speeds/robot_speed_pct", 50.0)
    ctx.queue.put(p)
    tick(root, ctx)
    policy = next(n for n in root.iterate() if isinstance(n, NextPart)).policy
    assert policy.robot_pct == 50.0
    r = ctx.cell.robot
    fixed = r.grip_s + r.release_s                 # only the moves scale with speed
    assert policy.cost(p, x_now, 0.0) == pytest.approx(2 * (full - fixed) + fixed)
