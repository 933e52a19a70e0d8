"""The belt window end to end: the shipped V+ programs in the emulator, the real driver, a
cell file whose window (700-1150 mm) is not the programs' default (770-1219 mm). The driver
sends it at connect (WINDOW); the arm never tracks past its downstream limit, a part past
the pick limit is refused, and a pick's reply comes with the arm off the belt, so an arm
whose link is lost after (or during) a pick stands still instead of following the belt."""

from __future__ import annotations

import dataclasses
import socket
import threading
import time

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.core.errors import EnvelopeError, MissedGrab
from feeder_bt.core.model import belt_window
from feeder_bt.emulators.adept import AdeptEmulator
from feeder_bt.emulators.vplus.trans import BeltLoc
from feeder_bt.hal.interfaces import PickTarget, Pose
from feeder_bt.sim.realtime import Plant
from tests.emulators.test_vplus_frames import _close, _rig
from tests.hal.test_adept_driver import (
    BELT_COUNTS_S,
    PARTS_AHEAD_S,
    WAIT_S,
    pickable_target,
    wait_for,
    wait_job,
)

# the base 70 mm further upstream than the simulated cell's, so that 700 mm is in reach
ROBOT = {"base_mm": (1300.0, 305.0), "safe_mm": (1300.0, -150.0),
         "belt_window_mm": (700.0, 1150.0), "pick_limit_mm": 1090.0}
DOWN = 1150.0


def _cell_and_plant():
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    cell = dataclasses.replace(cell, robot=dataclasses.replace(cell.robot, **ROBOT))
    plant = Plant(scenario, cell, seed=3).start()
    emu = AdeptEmulator(plant).start()
    plant.jog("A", BELT_COUNTS_S)
    plant.jog("B", BELT_COUNTS_S)
    plant.run_ahead(PARTS_AHEAD_S)
    return scenario, cell, plant, emu


def _arm_x(emu) -> float:
    """The arm's true cell-frame x now."""
    arm = emu.rt.arm
    return float((arm.true_base @ arm.here()).xyz[0])


class _Watch:
    """Samples, every few ms, the cell-frame x of the belt-relative location the arm moves
    to or tracks: the furthest downstream the arm ever followed the belt (its place and
    safe poses lie beyond the belt's end, off the belt)."""

    def __init__(self, emu) -> None:
        self.emu, self.max_x, self.stop = emu, -1e9, threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self.stop.is_set():
            arm = self.emu.rt.arm
            loc = arm.loc
            if isinstance(loc, BeltLoc):      # the belt point the arm goes to or tracks
                at = arm.true_base @ loc.at(self.emu.rt.track_count())
                self.max_x = max(self.max_x, float(at.xyz[0]))
            time.sleep(0.003)

    def close(self) -> float:
        self.stop.set()
        self.thread.join(1.0)
        return self.max_x


def _still(emu, seconds: float = 0.4) -> float:
    """How far the arm moved along x over ``seconds`` with the belt running."""
    x0 = _arm_x(emu)
    time.sleep(seconds)
    return abs(_arm_x(emu) - x0)


@pytest.fixture(scope="module")
def rig():
    plant, emu, ctrl, scenario = _rig(ROBOT, seed=3)
    try:
        yield scenario, load_scenario("scenarios/lenses.yaml")[1], plant, emu, ctrl
    finally:
        _close(plant, emu, ctrl)


def test_the_cell_files_window_reaches_the_controller(rig):
    _scenario, _cell, _plant, emu, ctrl = rig
    assert ctrl.window == (700.0, 1150.0, 1090.0)
    g = emu.rt.globals
    assert (g["belt.upx"].v, g["belt.downx"].v, g["pick.margin"].v) == (700.0, 1150.0, 60.0)


def test_the_arm_never_tracks_past_the_window_and_stops_tracking_with_each_pick(rig):
    scenario, _cell, plant, emu, ctrl = rig
    place = scenario.parts["lens"].place
    watch = _Watch(emu)
    landed, missed = 0, 0
    try:
        while landed < 3 and missed < 6:
            job = wait_job(ctrl.robot.pick(pickable_target(plant)))
            if isinstance(job.error, MissedGrab) or (
                    isinstance(job.error, EnvelopeError) and "-9004" in str(job.error)):
                # a loaded machine may starve the real-time arm, or send the pick after its
                # part rode past the pick limit: refused, as it must be
                missed += 1
                continue
            assert job.ok, job.error
            landed += 1
            # the reply came with the arm off the belt: it holds still as the belt runs
            assert not isinstance(emu.rt.arm.loc, BeltLoc)
            assert _still(emu) < 0.5
            assert wait_job(ctrl.robot.place(Pose(place.x, place.y, place.z, 0.0))).ok
        assert landed == 3, missed
        # a part already past the pick limit (1090 mm) is refused before the arm moves
        with plant.lock:
            latch = plant.world.robot_track_count(plant.world.now())
        late = PickTarget(part_id=99999, x_mm=1120.0, y_mm=300.0, angle_deg=0.0,
                          latch=latch, tracking=True)
        job = wait_job(ctrl.robot.pick(late))
        assert isinstance(job.error, EnvelopeError), job.error
    finally:
        furthest = watch.close()
    assert furthest <= DOWN + 0.5, furthest


def test_a_link_lost_during_a_pick_leaves_the_arm_standing_not_tracking():
    """The driver's socket cut (no reply read) while the arm is on its way: the pick runs
    to its end, and then the arm stands still where it departed, inside the window."""
    _scenario, cell, plant, emu = _cell_and_plant()
    watch = _Watch(emu)
    try:
        up, down, pick = belt_window(cell)
        bx, by = cell.robot.base_mm
        target = pickable_target(plant)
        with socket.create_connection(("127.0.0.1", emu.ports["motion"]), timeout=WAIT_S) as s:
            f = s.makefile("rwb")
            for line in ("HELLO", f"FRAME {bx:g} {by:g} 0", "DEFSAFE 1300 -150 0 0",
                         "BELTSCALE 0.05", f"WINDOW {up:g} {down:g} {pick:g}", "SPEED 100"):
                f.write((line + "\n").encode())
                f.flush()
                assert f.readline().startswith(b"OK"), line
            f.write((f"PICK {target.part_id} {target.x_mm:.2f} {target.y_mm:.2f} "
                     f"{target.angle_deg:.2f} {target.latch} 1 0 0 0 0\n").encode())
            f.flush()
            wait_for(lambda: emu.rt.arm.log, WAIT_S, "the arm to start")
        # the socket is gone; the pick goes on to its end, then the arm stops tracking
        wait_for(lambda: not isinstance(emu.rt.arm.loc, BeltLoc)
                 and not emu.rt.arm.busy(emu.rt.now()), WAIT_S, "the pick to end")
        assert _still(emu, 1.0) < 0.5           # 400 mm of belt meanwhile
    finally:
        furthest = watch.close()
        emu.stop()
        plant.stop()
    assert furthest <= DOWN + 0.5, furthest
