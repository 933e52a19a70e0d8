"""Tick-level tests of the present tree over the mock HAL."""

from __future__ import annotations

import pytest
from py_trees.common import Status

from feeder_bt.core.errors import ConveyorFault, HalError
from feeder_bt.trees import present
from tests.support.treeutil import bb_get, bb_set, fail, finish, make_ctx, tick


@pytest.fixture
def continuous():
    ctx = make_ctx()
    assert ctx.scenario.present.mode == "continuous"
    return ctx, present.build(ctx)


@pytest.fixture
def incremental():
    ctx = make_ctx(present={"mode": "incremental"})
    return ctx, present.build(ctx)


# ---------------------------------------------------------------------- continuous


def test_first_tick_runs_both_conveyors_at_blackboard_speeds(continuous):
    ctx, root = continuous
    assert tick(root, ctx) is Status.RUNNING
    h = ctx.scenario.present.horizontal_mm_s
    pct = ctx.scenario.present.incline_pct
    assert ctx.hal.calls == [("horizontal", "set_speed", (h,)),
                             ("incline", "set_speed", (h * pct / 100.0,))]
    assert ctx.hal.calls[1][2] == (60.0,)          # 150 mm/s at 40 %


def test_speeds_are_commanded_once_while_unchanged(continuous):
    ctx, root = continuous
    tick(root, ctx, n=10)
    finish(ctx.hal, "horizontal", "set_speed")
    finish(ctx.hal, "incline", "set_speed")
    tick(root, ctx, n=10)
    assert root.status is Status.RUNNING
    assert ctx.hal.methods() == ["horizontal.set_speed", "incline.set_speed"]


def test_new_blackboard_speed_is_commanded_on_next_tick(continuous):
    ctx, root = continuous
    tick(root, ctx, n=3)
    bb_set("/speeds/horizontal_mm_s", 200.0)
    tick(root, ctx)
    assert ctx.hal.calls[2:] == [("horizontal", "set_speed", (200.0,)),
                                 ("incline", "set_speed", (80.0,))]
    bb_set("/speeds/incline_pct", 50.0)
    tick(root, ctx)
    assert ctx.hal.calls[4:] == [("horizontal", "set_speed", (200.0,)),
                                 ("incline", "set_speed", (100.0,))]


def test_jam_is_shaken_loose_then_conveyors_run_again(continuous):
    ctx, root = continuous
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "set_speed")
    finish(ctx.hal, "incline", "set_speed")
    ctx.hal.conveyors["horizontal"].jam = ConveyorFault("horizontal conveyor stalled")
    ctx.hal.calls.clear()

    assert tick(root, ctx) is Status.RUNNING
    assert ctx.stats.faults["conveyor"] == 1
    assert ctx.hal.methods() == ["horizontal.shake"]
    tick(root, ctx, n=5)                    # the shake takes its time
    assert ctx.hal.methods() == ["horizontal.shake"]
    finish(ctx.hal, "horizontal", "shake")
    tick(root, ctx)
    assert ctx.stats.recoveries["conveyor"] == 1
    tick(root, ctx, n=30)                   # settle 0.5 s, then the speeds again
    assert ctx.hal.methods() == ["horizontal.shake", "horizontal.set_speed",
                                 "incline.set_speed"]
    assert ctx.hal.calls[1][2] == (150.0,)
    assert bb_get("/faults/escalate") is None


def test_second_jam_within_a_minute_goes_to_the_operator(continuous):
    ctx, root = continuous
    tick(root, ctx)
    ctx.hal.conveyors["horizontal"].jam = ConveyorFault("stalled")
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "shake")
    tick(root, ctx, n=40)
    assert bb_get("/faults/escalate") is None
    ctx.hal.conveyors["horizontal"].jam = ConveyorFault("stalled again")
    tick(root, ctx, n=2)
    assert "jammed again within a minute" in bb_get("/faults/escalate")
    assert ctx.stats.faults["conveyor"] == 2
    assert ctx.hal.methods().count("horizontal.shake") == 1


def test_other_conveyor_error_stops_and_retries(continuous):
    ctx, root = continuous
    tick(root, ctx)
    fail(ctx.hal, "horizontal", "set_speed", HalError("amplifier fault"))
    ctx.hal.calls.clear()
    assert tick(root, ctx) is Status.RUNNING
    assert ctx.stats.faults["hal"] == 1
    assert ctx.hal.methods() == ["horizontal.stop", "incline.stop"]
    finish(ctx.hal, "horizontal", "stop")
    finish(ctx.hal, "incline", "stop")
    tick(root, ctx, n=60)                   # 1 s back-off, then the speeds again
    assert ctx.hal.methods()[2:] == ["horizontal.set_speed", "incline.set_speed"]
    finish(ctx.hal, "horizontal", "set_speed")
    tick(root, ctx)
    assert bb_get("/faults/escalate") is None


def test_recovery_stop_failure_escalates(continuous):
    ctx, root = continuous
    tick(root, ctx)
    fail(ctx.hal, "incline", "set_speed", HalError("incline drive"))
    tick(root, ctx)
    fail(ctx.hal, "horizontal", "stop", ConveyorFault("no answer"))
    assert tick(root, ctx) is Status.RUNNING
    assert "conveyors do not respond" in bb_get("/faults/escalate")


def test_halting_the_tree_stops_the_conveyors(continuous):
    ctx, root = continuous
    tick(root, ctx, n=2)
    ctx.hal.calls.clear()
    root.stop(Status.INVALID)
    assert ctx.hal.methods() == ["horizontal.stop", "incline.stop"]
    assert ctx.hal.conveyors["horizontal"].speed() == 0.0
    assert ctx.hal.conveyors["incline"].speed() == 0.0


# ---------------------------------------------------------------------- incremental


def test_incremental_waits_for_a_request(incremental):
    ctx, root = incremental
    assert tick(root, ctx, n=20) is Status.RUNNING
    assert ctx.hal.calls == []


def test_incremental_small_advance(incremental):
    ctx, root = incremental
    tick(root, ctx, n=3)
    bb_set("/present/request", "small")
    tick(root, ctx)
    p = ctx.scenario.present
    v = ctx.cell.conveyors["horizontal"].max_mm_s
    assert ctx.hal.calls == [("horizontal", "move", (p.small_advance_mm, v))]
    tick(root, ctx, n=3)
    assert bb_get("/present/completed") == 0
    assert bb_get("/present/request") == "small"
    finish(ctx.hal, "horizontal", "move")
    tick(root, ctx)
    assert bb_get("/present/request") is None
    assert bb_get("/present/completed") == 1
    # served once only: no further motion until the next request
    tick(root, ctx, n=10)
    assert len(ctx.hal.calls) == 1


def test_incremental_big_advance_moves_both_belts(incremental):
    ctx, root = incremental
    bb_set("/present/request", "big")
    tick(root, ctx)
    p = ctx.scenario.present
    v = ctx.cell.conveyors["horizontal"].max_mm_s
    assert sorted(ctx.hal.calls) == sorted([("incline", "move", (p.big_advance_incline_mm, v)),
                                            ("horizontal", "move", (p.big_advance_mm, v))])
    assert (p.big_advance_mm, p.big_advance_incline_mm) == (1100.0, 400.0)
    finish(ctx.hal, "horizontal", "move")
    finish(ctx.hal, "incline", "move")
    tick(root, ctx)
    assert bb_get("/present/request") is None
    assert bb_get("/present/completed") == 1

    bb_set("/present/request", "small")
    tick(root, ctx)
    assert ctx.hal.calls[-1] == ("horizontal", "move", (p.small_advance_mm, v))
    finish(ctx.hal, "horizontal", "move")
    tick(root, ctx)
    assert bb_get("/present/completed") == 2


def test_incremental_big_advance_waits_for_the_incline_too(incremental):
    ctx, root = incremental
    bb_set("/present/request", "big")
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "move")
    tick(root, ctx, n=3)
    assert bb_get("/present/completed") == 0       # the incline is still moving
    finish(ctx.hal, "incline", "move")
    tick(root, ctx)
    assert bb_get("/present/completed") == 1


def test_incremental_halt_cancels_the_advance(incremental):
    ctx, root = incremental
    bb_set("/present/request", "big")
    tick(root, ctx)
    moves = ctx.hal.pending()
    assert len(moves) == 2
    root.stop(Status.INVALID)
    assert all(j.cancelled for j in moves)


def test_incremental_move_fault_is_recovered(incremental):
    ctx, root = incremental
    bb_set("/present/request", "small")
    tick(root, ctx)
    fail(ctx.hal, "horizontal", "move", ConveyorFault("following error"))
    tick(root, ctx)
    assert ctx.stats.faults["conveyor"] == 1
    assert ctx.hal.methods()[-1] == "horizontal.shake"     # a following error: a jam
    assert bb_get("/present/completed") == 0
    finish(ctx.hal, "horizontal", "shake")
    tick(root, ctx, n=30)                   # settle, then the request is served again
    assert ctx.hal.methods()[-1] == "horizontal.move"
    finish(ctx.hal, "horizontal", "move")
    tick(root, ctx)
    assert bb_get("/present/completed") == 1
