"""Tick-level tests of the retrieve tree over the mock HAL."""

from __future__ import annotations

import dataclasses

import pytest
from py_trees.common import Status

from feeder_bt.core.errors import EnvelopeError, MissedGrab, ServoTimeout
from feeder_bt.core.parts import Part
from feeder_bt.hal.interfaces import PickTarget, Pose
from feeder_bt.trees import retrieve
from tests.support.treeutil import (
    bb_get,
    bb_set,
    fail,
    finish,
    make_ctx,
    part,
    pending,
    scenario,
    tick,
)

MOTION = ("robot.pick", "robot.place", "robot.move_to", "robot.move_safe", "robot.recover")


@pytest.fixture
def tree():
    ctx = make_ctx()
    return ctx, retrieve.build(ctx)


def motion(ctx) -> list[str]:
    return [m for m in ctx.hal.methods() if m in MOTION]


def test_empty_queue_runs_without_robot_motion(tree):
    ctx, root = tree
    assert tick(root, ctx, n=50) is Status.RUNNING
    assert motion(ctx) == []
    # the only robot call is applying the blackboard speed once
    assert ctx.hal.calls == [("robot", "set_speed", (100.0,))]
    assert bb_get("/retrieve/part") is None


def test_queued_part_is_picked_placed_and_counted(tree):
    ctx, root = tree
    tick(root, ctx, n=3)
    p = part(420.0, -35.0, latch=12_345, angle_deg=30.0)
    ctx.queue.put(p)
    tick(root, ctx)
    assert len(ctx.queue) == 0
    job = pending(ctx.hal, "robot", "pick")
    assert job.args == (PickTarget(part_id=p.id, x_mm=420.0, y_mm=-35.0, angle_deg=30.0,
                                   latch=12_345, tracking=True, tool_offset=(0.0, 0.0, 0.0)),)
    assert bb_get("/retrieve/part") is p
    tick(root, ctx, n=3)
    assert motion(ctx) == ["robot.pick"]
    job.succeed(None)
    tick(root, ctx)
    place = pending(ctx.hal, "robot", "place")
    lens = ctx.scenario.parts["lens"].place
    assert place.args == (Pose(lens.x, lens.y, lens.z, 0.0),)     # lenses: no orient
    assert ctx.stats.total_retrieved == 0
    place.succeed(None)
    tick(root, ctx)
    assert ctx.stats.retrieved["lens"] == 1
    assert ctx.stats.counts["retrieved"] == 1
    assert ctx.stats.last_retrieved == "lens"
    tick(root, ctx, n=5)
    assert motion(ctx) == ["robot.pick", "robot.place"]


def test_place_orients_the_part_when_asked():
    scen, cell = scenario()
    lens = scen.parts["lens"]
    scen.parts["lens"] = dataclasses.replace(
        lens, place=dataclasses.replace(lens.place, orient=True),
        tool_offset=(1.0, 2.0, 3.0))
    ctx = make_ctx(scen, cell)
    root = retrieve.build(ctx)
    ctx.queue.put(part(400.0, 0.0, angle_deg=37.5))
    tick(root, ctx)
    assert pending(ctx.hal, "robot", "pick").args[0].tool_offset == (1.0, 2.0, 3.0)
    finish(ctx.hal, "robot", "pick")
    tick(root, ctx)
    assert pending(ctx.hal, "robot", "place").args[0] == Pose(1330.0, -120.0, 0.0, -37.5)


def test_squares_place_pose_is_oriented():
    scen, cell = scenario("squares")
    ctx = make_ctx(scen, cell)
    root = retrieve.build(ctx)
    ctx.queue.put(part(400.0, 0.0, type="square", angle_deg=-12.0))
    tick(root, ctx)
    finish(ctx.hal, "robot", "pick")
    tick(root, ctx)
    assert pending(ctx.hal, "robot", "place").args[0].rz == 12.0


def test_part_predicted_beyond_too_far_is_dropped(tree):
    ctx, root = tree
    r = ctx.scenario.retrieve
    lead = ctx.scenario.present.horizontal_mm_s * r.reach_time_s            # 52.5 mm
    cpm = ctx.cell.encoder.counts_per_mm
    late = part(900.0, latch=1_000)          # will have moved 250 mm: 1150 + lead > 1190
    ok = part(500.0, latch=1_000)            # 750 + lead: fine
    ctx.queue.put(late)
    ctx.queue.put(ok)
    ctx.hal.robot_position.encoder = 1_000 + int(250 * cpm)
    assert 900.0 + 250 + lead > r.too_far_mm > 500.0 + 250 + lead
    tick(root, ctx)
    assert ctx.stats.counts["too_far"] == 1
    assert [c[2][0].part_id for c in ctx.hal.calls if c[1] == "pick"] == [ok.id]
    assert len(ctx.queue) == 0


def test_only_part_too_far_gives_no_pick(tree):
    ctx, root = tree
    cpm = ctx.cell.encoder.counts_per_mm
    ctx.queue.put(part(1000.0, latch=-50))
    ctx.hal.robot_position.encoder = -50 + int(200 * cpm)
    assert tick(root, ctx, n=5) is Status.RUNNING
    assert ctx.stats.counts["too_far"] == 1
    assert motion(ctx) == []
    assert len(ctx.queue) == 0


def test_too_far_uses_the_encoder_not_the_clock(tree):
    ctx, root = tree
    ctx.queue.put(part(1000.0, latch=0))
    ctx.clock.advance(60.0)                 # a minute passes with the belt stopped
    tick(root, ctx)
    assert ctx.stats.counts["too_far"] == 0
    assert motion(ctx) == ["robot.pick"]


@pytest.mark.parametrize("policy, expected", [("fifo", 0), ("earliest_deadline", 1)])
def test_policy_chooses_the_part(policy, expected):
    ctx = make_ctx(retrieve={"policy": policy})
    root = retrieve.build(ctx)
    older = part(300.0, latch=0, located_at=1.0)       # seen first, further up the belt
    newer = part(200.0, latch=-4_000, located_at=2.0)  # seen later, but 200 mm further on
    ctx.queue.put(older)
    ctx.queue.put(newer)
    tick(root, ctx)
    target = pending(ctx.hal, "robot", "pick").args[0]
    assert target.part_id == (older, newer)[expected].id
    assert len(ctx.queue) == 1


def test_missed_grab_is_counted_and_next_part_follows(tree):
    ctx, root = tree
    first, second = part(300.0, located_at=1.0), part(350.0, located_at=2.0)
    ctx.queue.put(first)
    ctx.queue.put(second)
    tick(root, ctx)
    fail(ctx.hal, "robot", "pick", MissedGrab("nothing in the gripper"))
    tick(root, ctx)
    assert ctx.stats.counts["missed"] == 1
    assert ctx.stats.faults["missed_grab"] == 1
    assert motion(ctx) == ["robot.pick"]
    tick(root, ctx)
    picks = [c[2][0].part_id for c in ctx.hal.calls if c[1] == "pick"]
    assert picks == [first.id, second.id]
    assert bb_get("/retrieve/error") is None          # cleared for the new part
    assert bb_get("/faults/escalate") is None
    assert ctx.stats.total_retrieved == 0


def test_envelope_error_is_counted_as_unreachable(tree):
    ctx, root = tree
    ctx.queue.put(part(300.0))
    tick(root, ctx)
    fail(ctx.hal, "robot", "pick", EnvelopeError("out of reach"))
    assert tick(root, ctx) is Status.SUCCESS
    assert ctx.stats.counts["unreachable"] == 1
    assert ctx.stats.counts["missed"] == 0
    assert ctx.stats.faults["envelope"] == 1
    assert tick(root, ctx, n=5) is Status.RUNNING       # waits for the next part
    assert motion(ctx) == ["robot.pick"]
    assert bb_get("/faults/escalate") is None


def test_servo_timeout_recovers_and_retries_the_same_part(tree):
    ctx, root = tree
    p = part(300.0, 20.0, latch=777)
    ctx.queue.put(p)
    tick(root, ctx)
    first = pending(ctx.hal, "robot", "pick").args[0]
    fail(ctx.hal, "robot", "pick", ServoTimeout("joint 2"))
    tick(root, ctx)
    finish(ctx.hal, "robot", "recover")
    tick(root, ctx)
    finish(ctx.hal, "robot", "move_safe")
    tick(root, ctx)
    assert pending(ctx.hal, "robot", "pick").args[0] == first
    finish(ctx.hal, "robot", "pick")
    tick(root, ctx)
    finish(ctx.hal, "robot", "place")
    tick(root, ctx)
    assert ctx.hal.methods() == ["robot.set_speed", "robot.pick", "robot.recover",
                                 "robot.move_safe", "robot.pick", "robot.place"]
    assert ctx.stats.recoveries["servo_timeout"] == 1
    assert ctx.stats.faults["servo_timeout"] == 1
    assert ctx.stats.retrieved["lens"] == 1
    assert bb_get("/faults/escalate") is None


def test_failed_recovery_escalates_and_branch_stays_running(tree):
    ctx, root = tree
    ctx.queue.put(part(300.0))
    tick(root, ctx)
    fail(ctx.hal, "robot", "pick", ServoTimeout("joint 2"))
    tick(root, ctx)
    fail(ctx.hal, "robot", "recover", ServoTimeout("REACTE: power cannot be enabled"))
    assert tick(root, ctx) is Status.RUNNING
    reason = bb_get("/faults/escalate")
    assert reason == "robot could not recover: REACTE: power cannot be enabled"
    assert ctx.stats.recoveries["servo_timeout"] == 0
    n = len(ctx.hal.calls)
    ctx.queue.put(part(320.0))
    assert tick(root, ctx, n=10) is Status.RUNNING
    assert len(ctx.hal.calls) == n                    # no more motion once escalated
    assert bb_get("/faults/escalate") == reason


def test_second_servo_timeout_on_retry_recovers_again_and_lets_the_part_go(tree):
    ctx, root = tree
    ctx.queue.put(part(300.0))
    tick(root, ctx)
    fail(ctx.hal, "robot", "pick", ServoTimeout("joint 2"))
    tick(root, ctx)
    finish(ctx.hal, "robot", "recover")
    tick(root, ctx)
    finish(ctx.hal, "robot", "move_safe")
    tick(root, ctx)
    fail(ctx.hal, "robot", "pick", ServoTimeout("joint 2 again"))
    assert tick(root, ctx) is Status.RUNNING
    finish(ctx.hal, "robot", "recover")
    tick(root, ctx)
    finish(ctx.hal, "robot", "move_safe")
    tick(root, ctx, n=3)
    assert [m for m in ctx.hal.methods() if m != "robot.set_speed"] == [
        "robot.pick", "robot.recover", "robot.move_safe", "robot.pick", "robot.recover",
        "robot.move_safe"]                           # no third try at the same part
    assert ctx.stats.faults["servo_timeout"] == 2
    assert ctx.stats.recoveries["servo_timeout"] == 2
    assert bb_get("/faults/escalate") is None
    # a recovery that itself fails is the operator's
    ctx.queue.put(part(320.0))
    tick(root, ctx)
    fail(ctx.hal, "robot", "pick", ServoTimeout("joint 2"))
    tick(root, ctx)
    fail(ctx.hal, "robot", "recover", ServoTimeout("power cannot be enabled"))
    tick(root, ctx)
    assert "power cannot be enabled" in bb_get("/faults/escalate")


def test_robot_speed_follows_the_blackboard(tree):
    ctx, root = tree
    tick(root, ctx)
    bb_set("/speeds/robot_speed_pct", 60.0)
    ctx.queue.put(part(300.0))
    tick(root, ctx)
    finish(ctx.hal, "robot", "pick")
    tick(root, ctx)
    finish(ctx.hal, "robot", "place")
    tick(root, ctx, n=2)
    speeds = [c[2][0] for c in ctx.hal.calls if c[1] == "set_speed"]
    assert speeds == [100.0, 60.0]
    assert ctx.hal.robot.speed_pct == 60.0


def test_halt_while_picking_cancels_the_pick(tree):
    ctx, root = tree
    ctx.queue.put(part(300.0))
    tick(root, ctx)
    job = pending(ctx.hal, "robot", "pick")
    root.stop(Status.INVALID)
    assert job.cancelled


def test_pick_pre_empted_before_the_grip_puts_the_part_back():
    ctx = make_ctx()
    root = retrieve.build(ctx)
    ctx.queue.put(Part(id=7, type="lens", x_mm=900.0, y_mm=300.0, angle_deg=0.0, latch=0,
                       located_at=0.0))
    tick(root, ctx)
    pick = ctx.hal.last("robot", "pick")
    assert not pick.done and len(ctx.queue) == 0
    root.stop(Status.INVALID)                  # the cell pauses mid-pick
    assert pick.cancelled
    assert [p.id for p in ctx.queue.peek_all()] == [7]
