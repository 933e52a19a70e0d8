"""The grip's turn (``PickTarget.grip_deg``) reaches the robot.

The real driver against the shipped V+ programs run by the emulator, over TCP: PICK carries
``grip``, the tool closes turned by the part's angle plus the grip, PLACE turns the tool by
the same grip so the part lands as if gripped at its angle, and a PICK of nine arguments
(a driver of before the grip) is still taken, with a grip of 0 (vplus/PROTOCOL.md).
"""

from __future__ import annotations

import dataclasses

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.core.geometry import wrap_deg
from feeder_bt.emulators.adept import AdeptEmulator
from feeder_bt.hal.adept import protocol
from feeder_bt.hal.interfaces import Pose
from feeder_bt.sim.realtime import Plant
from tests.emulators.test_vplus_frames import _ask, _close, _rig
from tests.hal.test_adept_driver import pickable_target, wait_job

GRIP_DEG = 90.0


def test_the_pick_request_carries_the_grip():
    line = protocol.encode_request("motion", "PICK", 3, 700.0, 300.0, 10.0, 123, True,
                                   0.0, 0.0, 0.0, -37.5)
    assert line == "PICK 3 700 300 10 123 1 0 0 0 -37.5\n"
    assert protocol.command("motion", "PICK").args[-1] == "grip"


def test_the_tool_turns_to_the_grip_and_places_the_part_as_if_gripped_at_its_angle():
    plant, emu, ctrl, scenario = _rig()
    try:
        place = scenario.parts["lens"].place
        target = dataclasses.replace(pickable_target(plant, timeout=20.0), grip_deg=GRIP_DEG)
        job = wait_job(ctrl.robot.pick(target), 15.0)
        assert job.ok, job.error
        with plant.lock:
            world = plant.world
            assert world.gripper == target.part_id
            # the cup closed with the tool turned by the part's angle plus the grip ...
            assert abs(wrap_deg(world.robot_pose.rz - target.angle_deg - GRIP_DEG)) < 1.0
            # ... and the world judges the held part's angle from the part's, not the tool's
            assert abs(world.parts[target.part_id].held_error_deg) < 1.0
            assert emu.rt.globals["held.grip"].v == pytest.approx(GRIP_DEG)
        job = wait_job(ctrl.robot.place(Pose(place.x, place.y, place.z, 15.0)), 15.0)
        assert job.ok, job.error
        with plant.lock:
            assert world.parts[target.part_id].where == "placed"
            # released with the tool turned rz + grip: the part lands turned rz
            assert abs(wrap_deg(world.robot_pose.rz - 15.0 - GRIP_DEG)) < 1e-3
            assert emu.rt.globals["held.grip"].v == 0
    finally:
        _close(plant, emu, ctrl)


def test_a_pick_of_nine_arguments_is_still_taken_and_a_bad_grip_is_refused():
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    plant = Plant(scenario, cell, seed=1).start()
    emu = AdeptEmulator(plant).start()
    try:
        motion = emu.ports["motion"]
        frame = " ".join(protocol._fmt(v) for v in protocol.frame_args(cell.robot.base_mm,
                                                                       cell.robot.base_deg))
        assert _ask(motion, f"FRAME {frame}") == "OK"
        badarg = "ERR -9002"
        assert _ask(motion, "PICK 1 800 300 0 0 0 0 0 0 x").startswith(badarg)
        assert _ask(motion, "PICK 1 800 300 0 0 0 0 0 0 0 5").startswith(badarg)
        assert emu.rt.arm.log == []                       # refused before any motion
        reply = _ask(motion, "PICK 1 800 300 0 0 0 0 0 0")   # nine: grip 0
        assert not reply.startswith(badarg), reply
        assert emu.rt.arm.log                             # the arm went for it
        assert emu.rt.globals["pick.grip"].v == 0
    finally:
        emu.stop()
        plant.stop()
