"""Tick-level tests of the locate tree (continuous mode) over the mock HAL."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from py_trees.common import Status

from feeder_bt.core.errors import CommsLost, GrabFailed, HalError
from feeder_bt.trees import locate
from tests.support.treeutil import (
    bb_get,
    detection,
    fail,
    finish,
    frame,
    make_ctx,
    pending,
    result,
    tick,
)

CONV0 = 1_000                 # conveyor count at the encoder reset
ROBOT0 = 8_000_000            # robot count at the same moment
CPM = 20                      # counts per mm (cells/sim.yaml)


@pytest.fixture
def tree():
    ctx = make_ctx()
    ctx.encoder.reset(CONV0, ROBOT0)
    return ctx, locate.build(ctx)


def run_frame(ctx, root, latch: int, res, t: float = 0.0, index: int = 1):
    """Drive one frame: travel, grab, recipe, enqueue; returns the tree's status."""
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    finish(ctx.hal, "camera", "grab", frame(latch, t=t, index=index))
    tick(root, ctx)
    vjob = ctx.vision.jobs[-1]
    assert not vjob.done
    vjob.succeed(res)
    return tick(root, ctx)


def test_waits_for_travel_then_grabs(tree):
    ctx, root = tree
    assert tick(root, ctx, n=5) is Status.RUNNING
    assert ctx.hal.calls == [("horizontal", "travelled", (ctx.scenario.locate.frame_spacing_mm,))]
    assert ctx.hal.calls[0][2] == (300.0,)
    finish(ctx.hal, "horizontal", "travelled")
    assert tick(root, ctx) is Status.RUNNING
    assert ctx.hal.methods() == ["horizontal.travelled", "camera.grab"]
    tick(root, ctx, n=3)
    assert ctx.vision.jobs == []                    # no recipe before the frame arrives
    img_frame = frame(CONV0 + 100)
    pending(ctx.hal, "camera", "grab").succeed(img_frame)
    tick(root, ctx)
    assert len(ctx.vision.jobs) == 1
    assert ctx.vision.jobs[0].args[0] is img_frame.image
    assert bb_get("/locate/frame") is img_frame


def test_recipe_result_is_enqueued_with_robot_latch(tree):
    ctx, root = tree
    res = result(detection(150.0, 40.0, 12.5, area_mm2=2000.0),
                 detection(300.0, -60.0, pose="on_edge", pickable=False),
                 rejected=(SimpleNamespace(reason="outline does not match (0.61 < 0.75)",
                                           x_mm=90.0, y_mm=5.0,
                                           features={"area_mm2": 1500.0}),), ms=7.5)
    latch = CONV0 + 300 * CPM
    assert run_frame(ctx, root, latch, res, t=1.25, index=4) is Status.SUCCESS
    assert len(ctx.queue) == 1
    (p,) = ctx.queue.peek_all()
    assert (p.type, p.x_mm, p.y_mm, p.angle_deg) == ("lens", 150.0, 40.0, 12.5)
    assert p.latch == ROBOT0 + 300 * CPM
    assert p.located_at == 1.25
    assert p.frame == 4
    assert p.pose == "flat" and p.pickable
    assert p.features == {"area_mm2": 2000.0}
    s = ctx.stats
    assert s.counts["located"] == 1
    assert s.counts["located_unpickable"] == 1
    assert s.counts["rejected_blobs"] == 1
    assert s.counts["frames"] == 1
    assert s.vision_ms == [7.5]
    assert bb_get("/locate/found") == 1
    # the branch loops: the next tick waits for travel again
    tick(root, ctx)
    assert ctx.hal.methods()[-1] == "horizontal.travelled"
    assert len(ctx.hal.pending("horizontal", "travelled")) == 1


def test_latch_is_converted_across_robot_wrap():
    ctx = make_ctx()
    ctx.encoder.reset(CONV0, (1 << 23) - 100)       # robot counter about to wrap
    root = locate.build(ctx)
    run_frame(ctx, root, CONV0 + 300, result(detection(100.0, 0.0)))
    (p,) = ctx.queue.peek_all()
    assert p.latch == -(1 << 23) + 200


def test_same_part_in_next_frame_is_a_duplicate(tree):
    ctx, root = tree
    latch1 = CONV0 + 6000
    run_frame(ctx, root, latch1, result(detection(150.0, 40.0)), t=1.0, index=1)
    assert len(ctx.queue) == 1
    travel_mm = 300.0
    latch2 = latch1 + int(travel_mm * CPM)
    res2 = result(detection(150.0 + travel_mm, 40.0),      # the same lens, moved on
                  detection(150.0, 40.0))                   # a new lens where it was
    run_frame(ctx, root, latch2, res2, t=3.0, index=2)
    assert ctx.stats.counts["duplicates"] == 1
    assert ctx.stats.counts["located"] == 2
    parts = ctx.queue.peek_all()
    assert [(p.x_mm, p.frame) for p in parts] == [(150.0, 1), (150.0, 2)]
    assert parts[1].latch == ROBOT0 + 6000 + 6000
    assert bb_get("/locate/found") == 1


def test_part_not_matching_the_belt_travel_is_not_a_duplicate(tree):
    ctx, root = tree
    latch1 = CONV0 + 6000
    run_frame(ctx, root, latch1, result(detection(150.0, 40.0)))
    # only 100 mm of travel: a part at +300 mm is another part
    run_frame(ctx, root, latch1 + 100 * CPM, result(detection(450.0, 40.0)), index=2)
    assert ctx.stats.counts["duplicates"] == 0
    assert len(ctx.queue) == 2


def test_grab_failure_is_counted_backs_off_then_waits_for_travel(tree):
    ctx, root = tree
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    fail(ctx.hal, "camera", "grab", GrabFailed("no frame"))
    assert tick(root, ctx) is Status.RUNNING
    t0 = ctx.clock.now() - 0.02          # the back-off started in that tick
    assert ctx.stats.faults["grab_failed"] == 1
    assert isinstance(bb_get("/locate/error"), GrabFailed)
    assert bb_get("/faults/escalate") is None
    n_calls = len(ctx.hal.calls)
    t_travel = None
    for _ in range(30):
        t = ctx.clock.now()
        assert tick(root, ctx) is not Status.FAILURE
        if len(ctx.hal.calls) > n_calls:
            t_travel = t
            break
    # nothing during the 0.2 s back-off, then it waits for travel again
    assert t_travel is not None and t_travel >= t0 + 0.2 - 1e-9
    assert t_travel <= t0 + 0.2 + 0.02 + 1e-9
    assert ctx.hal.methods()[n_calls:] == ["horizontal.travelled"]
    assert ctx.stats.faults["grab_failed"] == 1
    assert ctx.vision.jobs == []


def test_terminate_while_grab_pending_cancels_it(tree):
    ctx, root = tree
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    grab = pending(ctx.hal, "camera", "grab")
    root.stop(Status.INVALID)
    assert grab.cancelled
    assert ctx.hal.pending() == []


def test_terminate_while_waiting_for_travel_cancels_the_notification(tree):
    ctx, root = tree
    tick(root, ctx)
    travel = pending(ctx.hal, "horizontal", "travelled")
    root.stop(Status.INVALID)
    assert travel.cancelled


def test_lost_link_is_retried_with_back_off_and_recovery_counted(tree):
    ctx, root = tree
    tick(root, ctx)
    fail(ctx.hal, "horizontal", "travelled", CommsLost("galil gone"))
    assert tick(root, ctx) is Status.RUNNING
    assert bb_get("/faults/escalate") is None
    assert ctx.stats.faults["comms_lost"] == 1
    n_calls = len(ctx.hal.calls)
    tick(root, ctx, n=20)                      # the first back-off is 0.5 s
    assert ctx.hal.methods()[n_calls:] == []
    tick(root, ctx, n=10)
    assert ctx.hal.methods()[n_calls:] == ["horizontal.travelled"]
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    assert ctx.stats.recoveries["comms_lost"] == 1
    assert ctx.hal.methods()[-1] == "camera.grab"


def test_lost_link_escalates_after_the_last_attempt(tree):
    ctx, root = tree
    tick(root, ctx)
    for _ in range(8):                         # back-offs 0.5, 1, 2, 4, 8, 8, 8, 8 s
        fail(ctx.hal, "horizontal", "travelled", CommsLost("galil gone"))
        tick(root, ctx, n=int(8.5 / 0.02))
        assert bb_get("/faults/escalate") is None
    fail(ctx.hal, "horizontal", "travelled", CommsLost("galil gone"))
    tick(root, ctx, n=2)
    assert bb_get("/faults/escalate") == "camera or vision failed: galil gone"
    assert ctx.stats.recoveries["comms_lost"] == 0


def test_travel_failure_after_a_grab_failure_is_not_taken_for_a_grab_failure(tree):
    ctx, root = tree
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    fail(ctx.hal, "camera", "grab", GrabFailed("no frame"))
    tick(root, ctx, n=15)                           # count, back off, wait for travel
    fail(ctx.hal, "horizontal", "travelled", CommsLost("galil gone"))
    tick(root, ctx)
    assert ctx.stats.faults["grab_failed"] == 1
    assert ctx.stats.faults["comms_lost"] == 1
    assert ctx.stats.recoveries["grab_failed"] == 0   # no grab has worked since
    assert bb_get("/faults/escalate") is None


def test_a_link_drop_during_a_grab_retry_leaves_both_faults_to_recover(tree):
    """The next notification proves the link back, the next frame the camera: each is
    counted recovered by the success that proves it (eight-hour shift, seed 5)."""
    ctx, root = tree
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    fail(ctx.hal, "camera", "grab", GrabFailed("no frame"))
    tick(root, ctx, n=15)
    fail(ctx.hal, "horizontal", "travelled", CommsLost("galil gone"))
    tick(root, ctx, n=60)                           # the link's back-off, 1 s (2nd in a row)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    assert dict(ctx.stats.recoveries) == {"comms_lost": 1}
    finish(ctx.hal, "camera", "grab", frame(0))
    tick(root, ctx)
    assert dict(ctx.stats.recoveries) == {"comms_lost": 1, "grab_failed": 1}
    assert dict(ctx.stats.faults) == {"grab_failed": 1, "comms_lost": 1}
    assert ctx.stats.pending == {}


def test_recipe_failure_is_counted_like_a_camera_fault(tree):
    ctx, root = tree
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    finish(ctx.hal, "camera", "grab", frame(CONV0))
    tick(root, ctx)
    ctx.vision.jobs[-1].fail(HalError("recipe crashed"))
    assert tick(root, ctx) is Status.RUNNING
    assert ctx.stats.faults["hal"] == 1
    assert len(ctx.queue) == 0
    assert bb_get("/faults/escalate") is None
    tick(root, ctx, n=15)
    assert ctx.hal.methods()[-1] == "horizontal.travelled"
