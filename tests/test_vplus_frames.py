"""The robot frame end to end: the shipped V+ programs in the emulator, over TCP, with the
real driver. Every pose goes through the cell frame the driver sends (FRAME), so a robot
base moved and turned in the cell file still picks, a wrong frame misses or is refused
(never feeds silently), a target outside the reach is refused before the arm moves, a
motion before FRAME is refused, and a STOP during a pick stops before the descent."""

from __future__ import annotations

import dataclasses
import socket
import time

import pytest

from feeder_bt.clock import RealClock
from feeder_bt.emulators.adept import AdeptEmulator
from feeder_bt.emulators.plant import Plant
from feeder_bt.errors import EnvelopeError, MissedGrab
from feeder_bt.hal.adept import AdeptController, VplusError
from feeder_bt.hal.interfaces import Pose
from feeder_bt.scenario import load_scenario
from tests.test_adept_driver import BELT_COUNTS_S, pickable_target, wait_for, wait_job

MOVED = {"base_mm": (1400.0, 330.0), "base_deg": 90.0}   # moved and turned 90 degrees


def _rig(robot: dict | None = None, true_base=None, seed: int = 4):
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    if robot:
        cell = dataclasses.replace(cell, robot=dataclasses.replace(cell.robot, **robot))
    plant = Plant(scenario, cell, seed=seed).start()
    emu = AdeptEmulator(plant, true_base=true_base).start()
    p = emu.ports
    spec = dataclasses.replace(cell.adept, host="127.0.0.1", motion_port=p["motion"],
                               position_port=p["position"], io_port=p["io"],
                               notify_port=p["notify"], timeout_s=2.0, motion_timeout_s=15.0)
    ctrl = AdeptController(spec, RealClock(), robot=cell.robot,
                           counts_per_mm=cell.encoder.counts_per_mm)
    plant.jog("A", BELT_COUNTS_S)
    plant.jog("B", BELT_COUNTS_S)
    return plant, emu, ctrl, scenario


def _close(plant, emu, ctrl) -> None:
    ctrl.close()
    emu.stop()
    plant.stop()
    assert plant.error is None


def _ask(port: int, line: str) -> str:
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall((line + "\n").encode())
        return s.makefile("rb").readline().decode().strip()


def test_a_motion_before_frame_answers_9008_and_here_is_in_robot_world():
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    plant = Plant(scenario, cell, seed=1).start()
    emu = AdeptEmulator(plant).start()
    try:
        motion, position = emu.ports["motion"], emu.ports["position"]
        for request in ("MOVE 1300 100 0 0", "SAFE", "PICK 1 800 300 0 0 1 0 0 0",
                        "PLACE 1330 -120 0 0"):
            assert _ask(motion, request) == "ERR -9008 *No cell frame*"
        assert _ask(position, "WHERE") == "ERR -9008 *No cell frame*"
        assert _ask(position, "HERE") == "OK 0.000 -455.000 0.000 0.000"   # safe, robot world
        assert _ask(motion, "DEFSAFE 1370 -150 0 0") == "ERR -9008 *No cell frame*"
        assert emu.rt.arm.log == []                   # nothing moved
    finally:
        emu.stop()
        plant.stop()


@pytest.fixture(scope="module")
def moved():
    plant, emu, ctrl, scenario = _rig(MOVED)
    try:
        yield plant, emu, ctrl, scenario
    finally:
        _close(plant, emu, ctrl)


def test_picks_land_on_parts_with_the_base_moved_and_turned(moved):
    plant, emu, ctrl, scenario = moved
    place = scenario.parts["lens"].place
    for _ in range(3):
        target = pickable_target(plant, timeout=20.0)
        job = wait_job(ctrl.robot.pick(target), 15.0)
        assert job.ok, job.error
        with plant.lock:
            assert plant.world.gripper == target.part_id       # the part aimed at
        job = wait_job(ctrl.robot.place(Pose(place.x, place.y, place.z, 0.0)), 15.0)
        assert job.ok, job.error
        with plant.lock:
            assert plant.world.parts[target.part_id].where == "placed"
            assert not plant.world.misplaced_by_type       # released at the place pose
    # WHERE answers in the cell frame, HERE in the robot's own (turned) frame
    assert wait_job(ctrl.robot.move_safe()).ok
    wait_for(lambda: ctrl.position.pose() == Pose(*plant.cell.robot.safe_mm), 2.0, "safe")
    here = _ask(emu.ports["position"], "HERE").split()
    bx, by = MOVED["base_mm"]
    sx, sy = plant.cell.robot.safe_mm            # Rot(-90) (safe - base)
    assert [float(v) for v in here[1:3]] == [pytest.approx(sy - by, abs=1e-3),
                                             pytest.approx(-(sx - bx), abs=1e-3)]


def test_a_target_outside_the_reach_is_refused_with_one_line(moved):
    plant, emu, ctrl, scenario = moved
    before = len(emu.rt.arm.log)
    job = wait_job(ctrl.robot.move_to(Pose(400.0, 300.0, 0.0, 0.0)))
    assert isinstance(job.error, EnvelopeError)
    assert str(job.error) == "V+ -610 *Location out of range* (MOVE)"
    assert len(emu.rt.arm.log) == before                  # the arm never moved


def test_a_wrong_frame_misses_or_is_refused_never_feeds_silently():
    # the cell file says the base is not turned; the arm is truly turned by 90 degrees
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    bx, by = cell.robot.base_mm
    plant, emu, ctrl, scenario = _rig(true_base=(bx, by, 90.0))
    try:
        failures = []
        for _ in range(3):
            target = pickable_target(plant, timeout=20.0)
            job = wait_job(ctrl.robot.pick(target), 15.0)
            assert not job.ok
            assert isinstance(job.error, (MissedGrab, EnvelopeError)), job.error
            failures.append(type(job.error).__name__)
        with plant.lock:
            world = plant.world
            assert world.gripper is None and world.counts["gripped"] == 0
            counted = world.counts["grip_empty"] + world.counts["grip_refused"]
        assert counted + failures.count("EnvelopeError") >= 3     # each one counted
    finally:
        _close(plant, emu, ctrl)


def test_stop_during_a_pick_stops_before_the_descent():
    plant, emu, ctrl, scenario = _rig()
    try:
        assert wait_job(ctrl.robot.set_speed(10)).ok          # a slow approach
        target = pickable_target(plant, timeout=20.0)
        job = ctrl.robot.pick(target)
        arm = emu.rt.arm
        wait_for(lambda: arm.motion is not None and arm.motion.kind == "appros"
                 and arm.busy(), 10.0, "the approach under way")
        assert wait_job(ctrl.robot.stop()).ok
        wait_job(job, 15.0)
        assert isinstance(job.error, VplusError) and job.error.code == -9006
        kinds = [k for k, _ in arm.log]
        assert kinds[-1] == "appros" and "moves" not in kinds   # no descent was started
        approach = plant.cell.robot.approach_mm
        assert all(z >= approach - 1e-6 for _, (_, _, z) in arm.log)
        time.sleep(0.05)                                       # the arm stays where it is
        assert arm.cell_pose()[2] > approach / 2               # never reached the belt z
        with plant.lock:
            assert plant.world.gripper is None
        assert wait_job(ctrl.robot.set_speed(100)).ok
        assert wait_job(ctrl.robot.move_safe()).ok             # the next motion runs
    finally:
        _close(plant, emu, ctrl)
