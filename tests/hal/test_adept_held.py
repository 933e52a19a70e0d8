"""Recovery that knows what it holds, robot link: the real driver against the V+
emulator, the link cut at each phase of a pick-and-place; after the reconnection
``held()`` tells the truth. Also STOP on a timed-out motion, the e-stop input, CR/LF in
requests and the belt channel's direction."""

from __future__ import annotations

import dataclasses
import socket

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.core.clock import RealClock
from feeder_bt.core.errors import CommsLost, PowerOff
from feeder_bt.emulators.adept import AdeptEmulator
from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.hal.adept import AdeptController
from feeder_bt.hal.adept.robot import AdeptRobot
from feeder_bt.hal.interfaces import Held, Pose
from feeder_bt.sim.realtime import Plant
from tests.hal.test_adept_driver import (
    BELT_COUNTS_S,
    MOTION_TIMEOUT_S,
    PARTS_AHEAD_S,
    TIMEOUT_S,
    WAIT_S,
    pickable_target,
    wait_for,
    wait_job,
)


def _rig(belt_direction: int = 1, spec_direction: str = "forward"):
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    plant = Plant(scenario, cell, seed=3).start()
    faults = FaultPlan()
    emu = AdeptEmulator(plant, faults=faults, belt_direction=belt_direction).start()
    p = emu.ports
    spec = dataclasses.replace(cell.adept, host="127.0.0.1", motion_port=p["motion"],
                               position_port=p["position"], io_port=p["io"],
                               notify_port=p["notify"], timeout_s=TIMEOUT_S,
                               motion_timeout_s=MOTION_TIMEOUT_S,
                               belt_direction=spec_direction)
    ctrl = AdeptController(spec, RealClock(), robot=cell.robot,
                           counts_per_mm=cell.encoder.counts_per_mm)
    plant.jog("A", BELT_COUNTS_S)
    plant.jog("B", BELT_COUNTS_S)
    plant.run_ahead(PARTS_AHEAD_S)
    return plant, emu, ctrl, faults, scenario


@pytest.fixture(scope="module")
def rig():
    plant, emu, ctrl, faults, scenario = _rig()
    try:
        yield plant, emu, ctrl, faults, scenario
    finally:
        ctrl.close()
        emu.stop()
        plant.stop()
    assert plant.error is None


def _place_pose(scenario) -> Pose:
    place = scenario.parts["lens"].place
    return Pose(place.x, place.y, place.z, 0.0)


def _where(plant: Plant, pid: int) -> str:
    with plant.lock:
        return "gripper" if plant.world.gripper == pid else plant.world.parts[pid].where


def _held(ctrl: AdeptController) -> Held:
    job = wait_job(ctrl.robot.held(), 15.0)
    assert job.ok, job.error
    return job.result


# ---------------------------------------------------------------------------- link cuts
def test_cut_before_the_pick_nothing_is_held(rig):
    plant, emu, ctrl, faults, scenario = rig
    faults.add("drop", "adept", "PICK", nth=1)
    target = pickable_target(plant)
    job = wait_job(ctrl.robot.pick(target))
    assert isinstance(job.error, CommsLost)
    held = _held(ctrl)
    assert held.empty and held.part_id is None and held.last_placed != target.part_id
    assert _where(plant, target.part_id) == "horizontal"      # never picked
    assert not ctrl.robot.holding()


def test_cut_after_the_grip_the_part_is_held_with_its_id(rig):
    plant, emu, ctrl, faults, scenario = rig
    faults.add("drop_after", "adept", "PICK", nth=1)
    target = pickable_target(plant)
    job = wait_job(ctrl.robot.pick(target))
    assert isinstance(job.error, CommsLost)
    assert _held(ctrl) == Held(part_id=target.part_id, unknown=False,
                               last_placed=_held(ctrl).last_placed)
    assert _where(plant, target.part_id) == "gripper"
    assert ctrl.robot.holding()
    # the cell places the part it now knows it holds
    assert wait_job(ctrl.robot.place(_place_pose(scenario))).ok
    assert _held(ctrl) == Held(part_id=None, unknown=False, last_placed=target.part_id)
    assert _where(plant, target.part_id) == "placed"


@pytest.mark.parametrize("kind", ["drop_during", "drop_after"])
def test_cut_during_or_after_the_place_the_part_is_placed(rig, kind):
    plant, emu, ctrl, faults, scenario = rig
    target = pickable_target(plant)
    assert wait_job(ctrl.robot.pick(target)).ok
    faults.add(kind, "adept", "PLACE", nth=1, after_s=0.1)
    if kind == "drop_during":
        assert wait_job(ctrl.robot.set_speed(10)).ok     # a place of several seconds
    try:
        job = wait_job(ctrl.robot.place(_place_pose(scenario)), 30.0)
        assert isinstance(job.error, CommsLost)
        if kind == "drop_during":             # the link went; the arm still carries it
            assert _where(plant, target.part_id) == "gripper"
        held = _held(ctrl)                    # answered once the place has ended
    finally:
        assert wait_job(ctrl.robot.set_speed(100)).ok
    assert held == Held(part_id=None, unknown=False, last_placed=target.part_id)
    assert _where(plant, target.part_id) == "placed"
    assert not ctrl.robot.holding()


def test_something_no_pick_of_ours_gripped_is_unknown(rig):
    plant, emu, ctrl, faults, scenario = rig
    target = pickable_target(plant)
    assert wait_job(ctrl.robot.pick(target)).ok
    emu.held_id = 0                           # e.g. a controller restarted with a part held
    held = _held(ctrl)
    assert held.unknown and held.part_id is None and not held.empty
    emu.held_id = target.part_id
    assert wait_job(ctrl.robot.place(_place_pose(scenario))).ok


# ---------------------------------------------------------------------------- STOP, e-stop
def test_a_timed_out_motion_stops_the_robot_before_the_link_is_dropped(rig):
    plant, emu, ctrl, faults, scenario = rig
    # the MOVE's reply is held until released: only the short motion time-out can end
    # the wait (the STOP is an ordinary request, with the generous time-out)
    impatient = AdeptRobot(ctrl.clients["motion"], ctrl.clock, motion_timeout_s=0.3,
                           timeout_s=TIMEOUT_S, stopper=ctrl.clients["position"])
    rule = faults.add("stall", "adept", "MOVE", nth=1, stall_s=3600.0)
    try:
        job = wait_job(impatient.move_to(Pose(900.0, 300.0, 0.0, 0.0)))
        assert isinstance(job.error, CommsLost) and "time-out" in str(job.error)
        assert impatient.stops == 1 and emu.stop_requested
        assert ("position", "STOP") in emu.requests
    finally:
        rule.release()
    assert wait_job(ctrl.robot.move_safe()).ok                 # the next motion runs
    assert not emu.stop_requested


def test_the_e_stop_input_refuses_motion_until_the_operator_resets(rig):
    plant, emu, ctrl, faults, scenario = rig
    plant.set_signal("estop", True)
    try:
        job = wait_job(ctrl.robot.move_safe())
        assert isinstance(job.error, PowerOff) and job.error.code == -9007
        job = wait_job(ctrl.robot.recover())
        assert isinstance(job.error, PowerOff) and job.error.code == -9007
        assert not emu.operator_reset()                       # not while it is pressed
    finally:
        plant.set_signal("estop", False)
    job = wait_job(ctrl.robot.move_safe())                    # released: power is still off
    assert isinstance(job.error, PowerOff) and job.error.code == -604
    assert emu.operator_reset()
    assert wait_job(ctrl.robot.move_safe()).ok


def test_a_stop_that_resets_itself_never_gets_arm_power_back_from_software(rig):
    """A guard door or light curtain on the e-stop input that resets itself: even a cell
    file that lets RECOVER turn power on (recover_power_on) gets -604, power stays off, and
    only a person at the controller brings it back; both codes are PowerOff, never the
    ServoTimeout whose recovery subtree would send RECOVER."""
    plant, emu, ctrl, faults, scenario = rig
    ctrl.robot.recover_power_on = True
    try:
        for _ in range(2):                                    # pressed and reset, twice
            plant.set_signal("estop", True)
            assert emu.estop_active()                         # the e-stop chain drops power
            job = wait_job(ctrl.robot.move_safe())
            assert isinstance(job.error, PowerOff) and job.error.code == -9007
            plant.set_signal("estop", False)                  # it resets itself
            job = wait_job(ctrl.robot.move_safe())
            assert isinstance(job.error, PowerOff) and job.error.code == -604
            job = wait_job(ctrl.robot.recover())              # RECOVER 1
            assert ("motion", "RECOVER 1") in emu.requests
            assert isinstance(job.error, PowerOff) and job.error.code == -604
            assert emu.power is False                         # no ENABLE POWER ran
            assert emu.operator_reset()                       # the person
            assert wait_job(ctrl.robot.move_safe()).ok
    finally:
        ctrl.robot.recover_power_on = False


# ---------------------------------------------------------------------------- lines, belt
def test_requests_ending_in_cr_lf_are_answered(rig):
    plant = rig[0]
    emu = AdeptEmulator(plant).start()       # its own servers: one client each
    try:
        _raw_requests(emu)
    finally:
        emu.stop()


def _raw_requests(emu: AdeptEmulator) -> None:
    with socket.create_connection(("127.0.0.1", emu.ports["io"]), timeout=WAIT_S) as s:
        s.sendall(b"HELLO\r\r\n")
        assert s.recv(100) == b"OK 2 io\r\n"
        s.sendall(b"SIG 1001 extra\r\n")                     # error echo as io.decode does
        assert s.recv(100) == b"ERR -9002 *Bad argument*\r\n"
    with socket.create_connection(("127.0.0.1", emu.ports["position"]), timeout=WAIT_S) as s:
        s.sendall(b"NOPE 1\r\n")                             # pos.decode: arity first
        assert s.recv(100) == b"ERR -9002 *Bad argument*\r\n"


def test_a_reversed_belt_channel_needs_the_reverse_setting():
    plant, emu, ctrl, faults, scenario = _rig(belt_direction=-1, spec_direction="reverse")
    try:
        # one POLL, bracketed by the true count (the belts are moving: a cached count may
        # be as old as the poller's last turn, which a loaded machine delays)
        pos = ctrl.position
        pos.stop()
        try:
            with plant.lock:
                before = plant.world.robot_count()
            pos.read_once()
            first = pos.belt_encoder()
            with plant.lock:
                after = plant.world.robot_count()
        finally:
            pos.start()

        def signed(counts: int) -> int:
            return ((counts + (1 << 23)) % (1 << 24)) - (1 << 23)

        # read with the reverse setting, it is the count the cell sees, between the two
        assert -4 <= signed(first - before) <= signed(after - before) + 4
        # beyond the simulated encoder's noise (a count or two either way at rest)
        wait_for(lambda: abs(ctrl.position.belt_encoder() - first) > 20,
                 what="belt count moving")
        moved = ctrl.position.belt_encoder() - first
        assert 20 < moved < (1 << 23)                         # counts forward, as the cell
        target = pickable_target(plant)                       # expects: picks track the belt
        job = wait_job(ctrl.robot.pick(target))
        assert job.ok, job.error
        assert _where(plant, target.part_id) == "gripper"
        assert wait_job(ctrl.robot.place(_place_pose(scenario))).ok
    finally:
        ctrl.close()
        emu.stop()
        plant.stop()
