"""Each recovery path of the trees, ticked through the fault and the recovery over the mock
HAL, asserting the order of the HAL calls."""

from __future__ import annotations

import pytest

from feeder_bt.control.cell import CellCommandError, CellState
from feeder_bt.core.errors import CommsLost, GrabFailed, ServoTimeout
from feeder_bt.trees import locate, retrieve
from tests.control.test_cell import Rig
from tests.support.treeutil import bb_get, fail, finish, frame, make_ctx, part, pending, tick

MOTION = ("robot.pick", "robot.place", "robot.move_safe", "robot.recover")


def robot_calls(ctx) -> list[str]:
    return [m for m in ctx.hal.methods() if m in MOTION]


def _place_fails_holding(error: Exception):
    """A retrieve tree whose first place fails with ``error``, the part in the gripper."""
    ctx = make_ctx()
    root = retrieve.build(ctx)
    ctx.queue.put(part(400.0))
    tick(root, ctx)
    finish(ctx.hal, "robot", "pick")
    ctx.hal.robot.gripping = True
    tick(root, ctx)
    fail(ctx.hal, "robot", "place", error)
    return ctx, root


def test_servo_timeout_during_place_recovers_and_places_the_held_part():
    ctx, root = _place_fails_holding(ServoTimeout("joint 1 following error"))
    tick(root, ctx)
    finish(ctx.hal, "robot", "recover")
    tick(root, ctx)
    finish(ctx.hal, "robot", "move_safe")
    tick(root, ctx)
    # the part is still in the gripper: place it, do not pick again
    assert robot_calls(ctx) == ["robot.pick", "robot.place", "robot.recover",
                                "robot.move_safe", "robot.place"]
    finish(ctx.hal, "robot", "place")
    ctx.hal.robot.gripping = False
    tick(root, ctx)
    assert ctx.stats.retrieved["lens"] == 1
    assert ctx.stats.faults["servo_timeout"] == 1
    assert ctx.stats.recoveries["servo_timeout"] == 1
    assert bb_get("/faults/escalate") is None


def test_lost_robot_link_backs_off_then_places_the_held_part_and_goes_on():
    ctx, root = _place_fails_holding(CommsLost("motion server: connection reset"))
    tick(root, ctx)
    assert ctx.stats.faults["comms_lost"] == 1
    tick(root, ctx, n=20)                       # back-off 0.5 s: no robot call meanwhile
    assert robot_calls(ctx) == ["robot.pick", "robot.place"]
    tick(root, ctx, n=10)
    assert robot_calls(ctx) == ["robot.pick", "robot.place", "robot.place"]
    finish(ctx.hal, "robot", "place")
    ctx.hal.robot.gripping = False
    tick(root, ctx)
    assert ctx.stats.recoveries["comms_lost"] == 1
    assert ctx.stats.retrieved["lens"] == 1
    ctx.queue.put(part(420.0))
    tick(root, ctx, n=2)
    assert robot_calls(ctx)[-1] == "robot.pick"          # feeding again
    assert bb_get("/faults/escalate") is None


def _to_grab(ctx, root):
    tick(root, ctx)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    return pending(ctx.hal, "camera", "grab")


def test_grab_failure_ladder_retry_then_new_golden_image_then_fault():
    ctx = make_ctx()
    root = locate.build(ctx)
    _to_grab(ctx, root)
    fail(ctx.hal, "camera", "grab", GrabFailed("no frame"))
    tick(root, ctx, n=15)                       # rung 1: back off, then try again
    assert bb_get("/faults/escalate") is None
    _to_grab(ctx, root)
    fail(ctx.hal, "camera", "grab", GrabFailed("no frame"))
    tick(root, ctx, n=25)                       # rung 2: clear the belt, new golden image
    travel = pending(ctx.hal, "horizontal", "travelled")
    assert travel.args == (ctx.cell.conveyors["horizontal"].length_mm,)
    assert bb_get("/present/hold") is True      # the incline waits while the belt empties
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    assert bb_get("/present/hold") is False
    assert ctx.hal.methods()[-2:] == ["horizontal.travelled", "camera.grab"]
    fail(ctx.hal, "camera", "grab", GrabFailed("camera gone"))    # rung 3: the operator
    tick(root, ctx, n=2)
    assert bb_get("/faults/escalate") == "camera or vision failed: camera gone"
    assert ctx.stats.faults["grab_failed"] == 1     # one fault, three attempts
    assert ctx.stats.retried["grab_failed"] >= 1    # the later ones: attempts, reported
    assert ctx.stats.recoveries["grab_failed"] == 0


def test_new_golden_image_counts_as_the_recovery():
    ctx = make_ctx()
    root = locate.build(ctx)
    for _ in range(2):
        _to_grab(ctx, root)
        fail(ctx.hal, "camera", "grab", GrabFailed("no frame"))
        tick(root, ctx, n=25)
    finish(ctx.hal, "horizontal", "travelled")
    tick(root, ctx)
    finish(ctx.hal, "camera", "grab", frame(0))
    tick(root, ctx)
    assert ctx.vision.golden is not None
    assert ctx.stats.recoveries["grab_failed"] == 1
    assert ctx.stats.attempts["/locate/error"] == 0


def test_estop_stops_every_motion_at_once_and_needs_an_operator_reset():
    rig = Rig()
    rig.start()
    rig.tick(3)
    rig.hal.conveyors["horizontal"].count = 100
    rig.hal.io.values["estop"] = True
    n = len(rig.hal.calls)
    running = [j for j in rig.hal.jobs if not j.done]
    rig.tick()
    assert rig.cell.state is CellState.FAULT          # at once: no clean-up motion
    assert rig.cell.fault_reason == "e-stop pressed"
    stops = rig.hal.methods()[n:]
    assert set(stops) == {"horizontal.stop", "incline.stop"}      # and nothing else
    assert all(j.cancelled for j in running)
    assert rig.cell.stats.faults["estop"] == 1
    rig.tick(50)
    assert rig.hal.methods()[n:] == stops
    with pytest.raises(CellCommandError, match="release it first"):
        rig.cell.reset()
    rig.hal.io.values["estop"] = False
    assert rig.cell.state is CellState.FAULT          # releasing is not a reset
    m = len(rig.hal.calls)
    rig.cell.reset()
    assert rig.cell.state is CellState.STOPPED
    # the operator's reset is what turns the belt motors back on
    assert sorted(rig.hal.methods()[m:]) == ["horizontal.servo", "incline.servo"]
    assert all(args == (True,) for _, meth, args in rig.hal.calls[m:])
    assert rig.cell.stats.recoveries["estop"] == 1
    rig.start()
    assert rig.cell.stats.faults["estop"] == 1        # the counts survive the restart


def test_estop_while_stopped_blocks_start():
    rig = Rig()
    rig.hal.io.values["estop"] = True
    with pytest.raises(CellCommandError, match="e-stop"):
        rig.cell.start()
    assert rig.cell.state is CellState.STOPPED
    assert rig.hal.calls == []


def test_a_part_held_through_an_estop_is_placed_first_after_the_restart():
    rig = Rig()
    rig.start()
    held = part(1000.0, 100.0)
    rig.cell.ctx.queue.put(held)
    rig.tick(2)
    finish(rig.hal, "robot", "pick")
    rig.hal.robot.gripping = True                  # gripped; the place is under way
    rig.tick()
    assert pending(rig.hal, "robot", "place")
    rig.hal.io.values["estop"] = True
    rig.tick()
    assert rig.cell.state is CellState.FAULT
    rig.hal.io.values["estop"] = False
    rig.cell.reset()
    rig.start()
    n = len(rig.hal.calls)
    rig.cell.ctx.queue.put(part(1000.0, 300.0))
    rig.tick()
    moves = [m for m in rig.hal.methods()[n:] if m.startswith("robot.") and "speed" not in m]
    assert moves == ["robot.held", "robot.place"]     # the controller's word, then the place
    rig.hal.robot.gripping = False
    finish(rig.hal, "robot", "place")
    rig.tick()
    assert rig.cell.stats.retrieved["lens"] == 1          # the held part, counted once
    assert pending(rig.hal, "robot", "pick")               # then feeding goes on


def test_a_part_the_run_did_not_pick_goes_to_the_operator():
    ctx = make_ctx()
    ctx.hal.robot.gripping = True                  # e.g. put in the gripper by hand
    root = retrieve.build(ctx)
    ctx.queue.put(part(1000.0, 100.0))
    tick(root, ctx)
    assert "did not pick" in bb_get("/faults/escalate")
    assert not ctx.hal.pending("robot", "pick")


@pytest.mark.parametrize("code", [-604, -9007])
def test_power_lost_to_a_stop_goes_to_a_person_and_never_to_recover(code):
    """An e-stop or a guard took the arm's power (V+ -604 or the server's -9007): the tree
    counts it and asks the cell for FAULT; it never runs the recovery program, whatever
    the cell file's recover_power_on says (a guard that resets itself must not give the
    arm its power back)."""
    from feeder_bt.hal.adept.protocol import error_text, vplus_error

    ctx, root = _place_fails_holding(vplus_error(code, error_text(code), "PLACE"))
    tick(root, ctx, n=5)
    assert robot_calls(ctx) == ["robot.pick", "robot.place"]        # no robot.recover
    assert ctx.stats.faults["power_off"] == 1
    assert "robot power off" in bb_get("/faults/escalate")
