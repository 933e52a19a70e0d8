"""The Adept driver against the V+ emulator on loopback, over the simulated cell in real
time: every command the HAL uses, a real tracking pick from the moving belt, error
replies and the V+ recovery, fault-plan faults, dropped links, input notifications."""

from __future__ import annotations

import dataclasses
import math
import threading
import time

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.core.clock import RealClock
from feeder_bt.core.errors import CommsLost, EnvelopeError, MissedGrab, PowerOff, ServoTimeout
from feeder_bt.core.jobs import Job, JobState
from feeder_bt.emulators.adept import AdeptEmulator, serve
from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.hal.adept import AdeptController, VplusError
from feeder_bt.hal.interfaces import PickResult, PickTarget, Pose
from feeder_bt.sim.realtime import Plant

BELT_COUNTS_S = 8000          # both belts at 400 mm/s (20 counts/mm): parts arrive fast
# The belts run this long (world seconds) at once after they are started (Plant.run_ahead):
# the first part comes into the reach ~4.7 s after the start (seeds 1-4), which a test
# would otherwise spend waiting in real time; it still waits for its part by condition.
PARTS_AHEAD_S = 4.0
# The driver's time-outs and the tests' waits only bound a hung test: a loaded machine may
# answer slowly, and no test is judged by how fast it does. A test of a time-out makes the
# controller truly silent (a stall released afterwards) and sets a short one for itself.
TIMEOUT_S = 10.0              # spec.timeout_s: short commands
MOTION_TIMEOUT_S = 30.0       # spec.motion_timeout_s: a pick, place or move
WAIT_S = 30.0                 # an event-driven wait in a test


def wait_job(job: Job, timeout: float = 2 * WAIT_S) -> Job:
    deadline = time.monotonic() + timeout
    while not job.done:
        assert time.monotonic() < deadline, f"{job} still running after {timeout} s"
        time.sleep(0.005)
    return job


def wait_for(cond, timeout: float = WAIT_S, what: str = "condition"):
    deadline = time.monotonic() + timeout
    while True:
        value = cond()
        if value:
            return value
        assert time.monotonic() < deadline, f"no {what} within {timeout} s"
        time.sleep(0.01)


@pytest.fixture(scope="module")
def rig():
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    plant = Plant(scenario, cell, seed=1).start()
    faults = FaultPlan()
    emu = AdeptEmulator(plant, faults=faults).start()
    ports = emu.ports
    spec = dataclasses.replace(cell.adept, host="127.0.0.1", motion_port=ports["motion"],
                               position_port=ports["position"], io_port=ports["io"],
                               notify_port=ports["notify"], timeout_s=TIMEOUT_S,
                               motion_timeout_s=MOTION_TIMEOUT_S)
    inputs = [s.bit for s in cell.io.values() if s.controller == "adept" and s.dir == "in"]
    ctrl = AdeptController(spec, RealClock(), inputs=inputs, robot=cell.robot)
    plant.jog("A", BELT_COUNTS_S)
    plant.jog("B", BELT_COUNTS_S)
    plant.run_ahead(PARTS_AHEAD_S)
    try:
        yield plant, emu, ctrl, faults, scenario
    finally:
        ctrl.close()
        emu.stop()
        plant.stop()
    assert plant.error is None


def pickable_target(plant: Plant, tool_offset=(0.0, 0.0, 0.0), timeout: float = WAIT_S
                    ) -> PickTarget:
    """Aim (tests only: from the ground truth) at a singulated, pickable part coming into
    the robot's reach, with the robot's encoder count at the same instant as the latch."""
    def find():
        with plant.lock:
            t = plant.world.now()
            rows = plant.world.truth(t)
            latch = plant.world.robot_track_count(t)
        # the part that entered last: the most time left in the window on a loaded machine
        for r in sorted(rows, key=lambda r: r["x_mm"]):
            alone = all(math.hypot(o["x_mm"] - r["x_mm"], o["y_mm"] - r["y_mm"]) > 70
                        for o in rows if o["id"] != r["id"])
            if (r["pickable"] and r["singulated"] and alone and 600 <= r["x_mm"] <= 800
                    and 60 <= r["y_mm"] <= 550):
                return PickTarget(part_id=r["id"], x_mm=r["x_mm"], y_mm=r["y_mm"],
                                  angle_deg=r["angle_deg"], latch=latch, tracking=True,
                                  tool_offset=tool_offset)
        return None

    return wait_for(find, timeout, "pickable part in reach")


def pick_and_place(plant: Plant, ctrl: AdeptController, scenario) -> PickResult:
    target = pickable_target(plant)
    job = wait_job(ctrl.robot.pick(target))
    assert job.state is JobState.SUCCEEDED, job.error
    result = job.result
    assert isinstance(result, PickResult) and result.part_id == target.part_id
    assert result.belt_x_mm > target.x_mm             # the belt carried it on: tracking
    assert ctrl.robot.holding()
    with plant.lock:
        assert plant.world.gripper == target.part_id   # the very part we aimed at
    place = scenario.parts["lens"].place
    job = wait_job(ctrl.robot.place(Pose(place.x, place.y, place.z, 0.0)))
    assert job.ok, job.error
    assert not ctrl.robot.holding()
    with plant.lock:
        assert plant.world.gripper is None
        assert plant.world.parts[target.part_id].where == "placed"
    return result


# ---------------------------------------------------------------------------- position
def test_position_cache_follows_the_belt_and_the_robot(rig):
    plant, emu, ctrl, faults, scenario = rig
    pos = ctrl.position
    assert pos.pose() == Pose(*plant.cell.robot.safe_mm)
    wait_for(lambda: pos.updated_at is not None, what="a first poll")
    # one POLL: the cached count is one the controller had between before and after
    pos.stop()
    try:
        with plant.lock:
            before = plant.world.robot_count()
        pos.read_once()
        cached = pos.belt_encoder()
        with plant.lock:
            after = plant.world.robot_count()
    finally:
        pos.start()
    span = (after - before) % (1 << 24)
    assert (cached - before) % (1 << 24) <= span
    first = pos.belt_encoder()
    wait_for(lambda: pos.belt_encoder() != first, what="belt count moving")
    callers: list[int] = []
    real_call = pos.position.call

    def spy(*a, **kw):
        callers.append(threading.get_ident())
        return real_call(*a, **kw)

    pos.position.call = spy
    try:
        for _ in range(1000):                         # reads come from the cache
            pos.belt_encoder()
            pos.pose()
        wait_for(lambda: callers, what="a poll")      # the poller goes on meanwhile
    finally:
        del pos.position.call
    assert threading.get_ident() not in callers       # no socket round trip per read
    # one POLL per period carries both the pose and the count
    kinds = {line for server, line in emu.requests if server == "position"}
    assert kinds == {"HELLO", "POLL"}                 # never WHERE and BELT apart


def test_motion_commands_and_position_mid_motion(rig):
    plant, emu, ctrl, faults, scenario = rig
    robot, pos = ctrl.robot, ctrl.position
    assert wait_job(robot.set_speed(50)).ok
    # the motion server holds the MOVE's reply until released, so the motion stays in
    # flight for as long as the test needs, however slowly the machine runs the test
    rule = faults.add("stall", "adept", "MOVE", nth=1, stall_s=3600.0)
    try:
        job = robot.move_to(Pose(900.0, 400.0, 0.0, 30.0))
        assert not job.done                           # returns at once, still moving
        counts = set()

        def polled_on() -> bool:                      # the position socket answers meanwhile
            counts.add(pos.belt_encoder())
            return len(counts) > 3
        wait_for(polled_on, what="fresh belt counts while the motion is in flight")
        assert not job.done
    finally:
        rule.release()
    assert wait_job(job).ok and job.result == Pose(900.0, 400.0, 0.0, 30.0)
    wait_for(lambda: pos.pose() == Pose(900.0, 400.0, 0.0, 30.0), what="new pose")
    assert wait_job(robot.set_speed(100)).ok
    assert wait_job(robot.move_safe()).ok
    wait_for(lambda: pos.pose() == Pose(*plant.cell.robot.safe_mm), what="safe pose")
    assert not robot.holding()


# ---------------------------------------------------------------------------- picking
def test_tracking_pick_from_the_moving_belt_and_place(rig):
    plant, emu, ctrl, faults, scenario = rig
    pick_and_place(plant, ctrl, scenario)


def test_out_of_reach_pick_is_an_envelope_error(rig):
    plant, emu, ctrl, faults, scenario = rig
    job = wait_job(ctrl.robot.pick(PickTarget(1, 0.0, 0.0, 0.0, 0, tracking=False)))
    assert isinstance(job.error, EnvelopeError)
    assert job.error.code == -610 and "*Location out of range*" in str(job.error)
    with plant.lock:
        latch = plant.world.robot_count()
    job = wait_job(ctrl.robot.pick(PickTarget(2, 2200.0, 300.0, 0.0, latch, tracking=True)))
    assert isinstance(job.error, EnvelopeError) and job.error.code == -9004
    assert not ctrl.robot.holding()


def test_nothing_under_the_gripper_is_a_missed_grab(rig):
    plant, emu, ctrl, faults, scenario = rig
    # y = 600 mm: beyond the rails, no part's centre can be within the grip tolerance
    job = wait_job(ctrl.robot.pick(PickTarget(3, 1000.0, 600.0, 0.0, 0, tracking=False)))
    assert isinstance(job.error, MissedGrab) and job.error.code == -9003
    assert not ctrl.robot.holding()
    assert wait_job(ctrl.robot.move_safe()).ok


def test_servo_timeout_needs_recover_then_picking_works(rig):
    plant, emu, ctrl, faults, scenario = rig
    faults.add("servo_timeout", "adept", "PICK", nth=1)
    with plant.lock:
        latch = plant.world.robot_count()
    job = wait_job(ctrl.robot.pick(PickTarget(4, 900.0, 300.0, 0.0, latch)))
    assert isinstance(job.error, ServoTimeout) and job.error.code == -1007
    assert "*Motor stalled*" in str(job.error)
    # REACTE turned power off: every motion fails until RECOVER (-604: power is off,
    # which the trees leave to a person unless a servo fault came first)
    job = wait_job(ctrl.robot.move_safe())
    assert isinstance(job.error, PowerOff) and job.error.code == -604
    # the cell description does not allow RECOVER to turn power on (the default): the
    # fault is cleared, power stays off until the operator's reset
    assert ctrl.robot.recover_power_on is False
    job = wait_job(ctrl.robot.recover())
    assert isinstance(job.error, PowerOff) and job.error.code == -604
    assert ("motion", "RECOVER 0") in emu.requests and emu.power is False
    assert isinstance(wait_job(ctrl.robot.move_safe()).error, PowerOff)
    assert emu.operator_reset()
    job = wait_job(ctrl.robot.recover())
    assert job.ok, job.error
    assert wait_job(ctrl.robot.move_safe()).ok
    # a cell description that allows it: RECOVER 1 turns power on by itself
    faults.add("servo_timeout", "adept", "MOVE", nth=1)
    assert isinstance(wait_job(ctrl.robot.move_to(Pose(900.0, 300.0))).error, ServoTimeout)
    ctrl.robot.recover_power_on = True
    try:
        job = wait_job(ctrl.robot.recover())
        assert job.ok, job.error
        assert ("motion", "RECOVER 1") in emu.requests and emu.power is True
    finally:
        ctrl.robot.recover_power_on = False
    assert wait_job(ctrl.robot.move_safe()).ok
    pick_and_place(plant, ctrl, scenario)


# ---------------------------------------------------------------------------- faults, links
def test_rejected_command_is_a_vplus_error(rig):
    plant, emu, ctrl, faults, scenario = rig
    faults.add("reject", "adept", "SPEED", nth=1)
    job = wait_job(ctrl.robot.set_speed(80))
    assert type(job.error) is VplusError and job.error.code == -9005
    assert wait_job(ctrl.robot.set_speed(100)).ok


def test_dropped_socket_is_comms_lost_and_the_driver_reconnects(rig):
    plant, emu, ctrl, faults, scenario = rig
    before = emu.connections["motion"]
    faults.add("drop", "adept", "SPEED", nth=1)
    job = wait_job(ctrl.robot.set_speed(90))
    assert isinstance(job.error, CommsLost)
    assert wait_job(ctrl.robot.set_speed(100)).ok      # re-connected after the back-off
    assert emu.connections["motion"] == before + 1

    # the network drops every link: the poller and the notify listener come back too
    counts = {k: emu.connections[k] for k in ("position", "io", "notify")}
    emu.drop_clients()
    wait_for(lambda: all(emu.connections[k] > counts[k] for k in ("position", "notify")),
             what="position and notify re-connected")
    t_drop = time.monotonic()
    wait_for(lambda: ctrl.position.updated_at > t_drop, what="fresh position after the drop")
    # an idle link the server closed is noticed before the next request goes out
    assert wait_job(ctrl.io.set(2, False)).ok
    assert wait_job(ctrl.robot.set_speed(100)).ok


def test_stalled_reply_times_out_then_the_link_recovers(rig):
    plant, emu, ctrl, faults, scenario = rig
    # the controller holds the reply until released: only the time-out can end the wait,
    # so a short one is safe (no slow machine answers it late, none trips it early)
    rule = faults.add("stall", "adept", "SPEED", nth=1, stall_s=3600.0)
    ctrl.robot.timeout_s = 0.5
    try:
        job = wait_job(ctrl.robot.set_speed(70))
    finally:
        ctrl.robot.timeout_s = TIMEOUT_S
        rule.release()
    assert isinstance(job.error, CommsLost) and "time-out" in str(job.error)
    assert wait_job(ctrl.robot.set_speed(100)).ok


# ---------------------------------------------------------------------------- I/O
def test_input_change_reaches_changes_through_the_notify_socket(rig):
    plant, emu, ctrl, faults, scenario = rig
    io = ctrl.io
    io.changes()
    connects = ctrl.notify_link.connects
    assert io.get(1) is False                          # estop: adept input bit 1
    plant.set_signal("estop", True)
    got = wait_for(io.changes, what="input change")
    assert [(b, v) for b, v, _ in got] == [(1, True)]
    assert io.get(1) is True
    plant.set_signal("estop", False)
    got = wait_for(io.changes, what="input change")
    assert [(b, v) for b, v, _ in got] == [(1, False)]
    assert got[0][2] <= ctrl.clock.now()
    assert ctrl.notify_link.connects == connects      # one connection carried both lines


def test_outputs_are_set_through_the_io_socket(rig):
    plant, emu, ctrl, faults, scenario = rig
    job = ctrl.io.set(2, True)                         # vacuum: adept output bit 2
    assert wait_job(job).ok
    assert plant.signal("vacuum") is True and ctrl.io.get(2) is True
    assert wait_job(ctrl.io.set(2, False)).ok
    assert plant.signal("vacuum") is False and ctrl.io.get(2) is False


def test_serve_picks_consecutive_ports_and_wrong_wiring_is_detected():
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    plant = Plant(scenario, cell, seed=2).start()
    emu = serve(plant)                                 # free ports
    try:
        p = emu.ports
        assert len(set(p.values())) == 4
        swapped = dataclasses.replace(cell.adept, motion_port=p["position"],
                                      position_port=p["motion"], io_port=p["io"],
                                      notify_port=p["notify"], timeout_s=TIMEOUT_S)
        with pytest.raises(CommsLost, match="answers as the 'position' server"):
            AdeptController(swapped, RealClock(), robot=cell.robot)
        right = dataclasses.replace(swapped, motion_port=p["motion"], position_port=p["position"])
        ctrl = AdeptController(right, RealClock(), robot=cell.robot)
        ctrl.close()                                   # a closed driver fails jobs, never raises
        job = ctrl.robot.move_safe()
        assert job.state is JobState.FAILED and isinstance(job.error, CommsLost)
        assert ctrl.io.set(2, True).state is JobState.FAILED
    finally:
        emu.stop()
        plant.stop()
