"""The Cell over the mock HAL and a SimClock: commands, state changes and the trees it ticks."""

from __future__ import annotations

import pytest

from tests.support.treeutil import DT, fail, frame, pending, scenario

# Cell builds a Locator from the scenario; until feeder_bt/vision/locator.py lands, skip
# (loudly) rather than fail at import.
pytest.importorskip("feeder_bt.vision.locator",
                    reason="feeder_bt.vision.locator.Locator not written yet")

from feeder_bt.behaviours.keys import FAULTS  # noqa: E402
from feeder_bt.control.cell import Cell, CellCommandError, CellState  # noqa: E402
from feeder_bt.core.clock import SimClock  # noqa: E402
from feeder_bt.core.errors import ConveyorFault, HalError, ServoTimeout  # noqa: E402
from feeder_bt.hal.mock.hal import MockHal  # noqa: E402

SETUP_CALLS = ["robot.set_speed", "robot.move_safe", "horizontal.stop", "incline.stop",
               "io.set", "horizontal.move", "camera.grab"]


class Rig:
    def __init__(self, name: str = "lenses") -> None:
        self.scenario, self.spec = scenario(name)
        self.hal = MockHal()
        self.clock = SimClock()
        self.cell = Cell(self.spec, self.hal, self.clock)
        self.cell.load(self.scenario)

    def tick(self, n: int = 1) -> None:
        for _ in range(n):
            self.cell.tick()
            self.clock.advance(DT)

    def finish_new(self, since: int) -> int:
        """Succeed every job still running that was created at index ``since`` or later."""
        n = 0
        for job in self.hal.jobs[since:]:
            if not job.done:
                job.succeed(frame(0, t=self.clock.now()) if job.name == "camera.grab" else None)
                n += 1
        return n

    def drive_until(self, state: CellState, max_s: float = 5.0) -> float:
        """Tick at 50 Hz, finishing each new job as it appears, until ``state``; returns
        the clock time it took."""
        since, t0 = len(self.hal.jobs), self.clock.now()
        while self.cell.state is not state:
            assert self.clock.now() - t0 < max_s, (self.cell.state, self.hal.methods())
            self.tick()
            self.finish_new(since)
        return self.clock.now() - t0

    def start(self) -> None:
        self.cell.start()
        assert self.cell.state is CellState.STARTING
        self.drive_until(CellState.RUNNING)


@pytest.fixture
def rig():
    r = Rig()
    yield r
    if r.cell.ctx is not None and r.cell.ctx.vision is not None:
        r.cell.ctx.vision.close()


def test_start_runs_setup_in_order_then_running(rig):
    rig.hal.conveyors["horizontal"].count = 5_000
    rig.hal.robot_position.encoder = 8_000_000
    rig.cell.start()
    assert rig.cell.state is CellState.STARTING
    rig.drive_until(CellState.RUNNING)
    assert rig.hal.methods() == SETUP_CALLS
    calls = rig.hal.calls
    assert calls[0] == ("robot", "set_speed", (100.0,))
    assert calls[4] == ("io", "set", ("backlight", True))
    cam = rig.spec.camera
    clear_mm = cam.height_px * cam.calibration.mm_per_px + 2 * 50.8 + 60.0
    assert calls[5] == ("horizontal", "move", (pytest.approx(clear_mm), 400.0))
    assert rig.hal.io.values["backlight"] is True
    assert rig.cell.encoder.reference == (5_000, 8_000_000)
    assert rig.cell.stats.counts["frames"] == 0
    assert any(ev.kind == "golden_image" for ev in rig.cell.stats.events)


def test_running_ticks_the_feeding_tree(rig):
    rig.start()
    n = len(rig.hal.calls)
    rig.tick()
    new = rig.hal.methods()[n:]
    assert new[:2] == ["horizontal.set_speed", "incline.set_speed"]
    assert "horizontal.travelled" in new
    assert rig.cell.state is CellState.RUNNING


def test_setup_waits_for_each_job(rig):
    rig.cell.start()
    rig.tick(10)
    assert rig.hal.methods() == ["robot.set_speed", "robot.move_safe"]
    assert rig.cell.state is CellState.STARTING


def test_pause_cancels_jobs_and_stops_conveyors_then_resume(rig):
    rig.start()
    rig.tick(3)
    running = rig.hal.pending()
    assert {j.name for j in running} >= {"horizontal.travelled", "horizontal.set_speed",
                                         "incline.set_speed"}
    n = len(rig.hal.calls)
    rig.cell.pause()
    assert rig.cell.state is CellState.PAUSED
    assert all(j.cancelled for j in running)
    assert {"horizontal.stop", "incline.stop"} <= set(rig.hal.methods()[n:])
    assert rig.hal.conveyors["horizontal"].speed() == 0.0
    assert rig.hal.conveyors["incline"].speed() == 0.0
    assert all(j.name.endswith(".stop") for j in rig.hal.pending())
    # nothing is ticked while paused
    n = len(rig.hal.calls)
    rig.tick(20)
    assert len(rig.hal.calls) == n
    with pytest.raises(CellCommandError):
        rig.cell.pause()

    rig.cell.resume()
    assert rig.cell.state is CellState.RUNNING
    rig.tick()
    new = rig.hal.calls[n:]
    assert ("horizontal", "set_speed", (150.0,)) in new
    assert ("horizontal", "travelled", (300.0,)) in new


def test_stop_with_empty_queue_reaches_stopped_within_a_second(rig):
    rig.start()
    rig.tick(10)
    assert len(rig.cell.ctx.queue) == 0
    n = len(rig.hal.calls)
    rig.cell.stop()
    assert rig.cell.state is CellState.STOPPING
    took = rig.drive_until(CellState.STOPPED, max_s=1.0)
    assert took <= 1.0
    new = rig.hal.calls[n:]
    assert ("io", "set", ("backlight", False)) in new
    assert rig.hal.io.values["backlight"] is False
    assert [m for m in rig.hal.methods()[n:] if m == "robot.move_safe"] == ["robot.move_safe"]
    assert rig.hal.conveyors["horizontal"].speed() == 0.0
    assert rig.cell.root is None
    # stopped: ticking does nothing
    n = len(rig.hal.calls)
    rig.tick(10)
    assert len(rig.hal.calls) == n


def test_start_again_after_stop_and_switch_scenario(rig):
    rig.start()
    with pytest.raises(CellCommandError):
        rig.cell.load(scenario("squares")[0])
    with pytest.raises(CellCommandError):
        rig.cell.start()
    rig.cell.stop()
    rig.drive_until(CellState.STOPPED)

    rig.start()                                  # the same scenario again
    assert rig.cell.ctx.scenario.name == "lenses"
    rig.cell.stop()
    rig.drive_until(CellState.STOPPED)

    squares = scenario("squares")[0]
    rig.cell.load(squares)
    assert rig.cell.scenario is squares
    n = len(rig.hal.calls)
    rig.start()
    assert rig.cell.state is CellState.RUNNING
    assert rig.cell.ctx.scenario.name == "squares"
    assert rig.hal.methods()[n:] == SETUP_CALLS
    rig.tick()
    # squares: incline at 50 % of 150 mm/s
    assert ("incline", "set_speed", (75.0,)) in rig.hal.calls[n:]


def test_start_without_scenario_is_refused():
    spec = scenario()[1]
    cell = Cell(spec, MockHal(), SimClock())
    with pytest.raises(CellCommandError):
        cell.start()
    assert cell.state is CellState.STOPPED


def test_escalation_on_blackboard_drives_cell_to_fault(rig):
    rig.start()
    rig.tick(2)
    rig.cell.board.set(FAULTS.ESCALATE, "operator test")
    rig.tick()
    assert rig.cell.state is CellState.FAULTING
    assert rig.cell.fault_reason == "operator test"
    rig.drive_until(CellState.FAULT, max_s=1.0)
    assert ("io", "set", ("backlight", False)) in rig.hal.calls
    with pytest.raises(CellCommandError):
        rig.cell.start()
    rig.cell.reset()
    assert rig.cell.state is CellState.STOPPED
    assert rig.cell.fault_reason is None
    rig.start()                                   # and it can run again
    assert rig.cell.board.get(FAULTS.ESCALATE) is None


def test_conveyor_that_cannot_stop_faults_the_cell(rig):
    rig.start()
    rig.tick()
    fail(rig.hal, "horizontal", "set_speed", HalError("amplifier fault"))
    rig.tick()                                    # recovery: count, stop the conveyors
    assert rig.cell.state is CellState.RUNNING
    assert rig.cell.stats.faults["hal"] == 1
    fail(rig.hal, "horizontal", "stop", ConveyorFault("no answer"))
    rig.tick()
    assert rig.cell.state is CellState.FAULTING
    assert "conveyors do not respond" in rig.cell.fault_reason
    assert any(ev.kind == "fault" and ev.data.get("kind") == "cell"
               for ev in rig.cell.stats.events)
    rig.drive_until(CellState.FAULT)
    assert rig.hal.io.values["backlight"] is False
    rig.cell.reset()
    assert rig.cell.state is CellState.STOPPED


def test_stop_during_setup_cancels_it(rig):
    rig.cell.start()
    rig.tick()
    move = pending(rig.hal, "robot", "move_safe")
    rig.cell.stop()
    assert move.cancelled
    rig.drive_until(CellState.STOPPED, max_s=1.0)


def test_stop_from_paused_reaches_stopped(rig):
    rig.start()
    rig.tick(2)
    rig.cell.pause()
    rig.cell.stop()
    assert rig.cell.state is CellState.STOPPING
    rig.drive_until(CellState.STOPPED, max_s=1.0)
    assert rig.hal.io.values["backlight"] is False


def test_setup_failure_faults_the_cell(rig):
    rig.cell.start()
    rig.tick()
    # (not a servo time-out: set-up runs the recovery program for that, as clean-up does)
    fail(rig.hal, "robot", "move_safe", HalError("joint 1"))
    rig.tick()
    assert rig.cell.state is CellState.FAULTING
    assert rig.cell.fault_reason == "set-up failed: joint 1"
    rig.drive_until(CellState.FAULT, max_s=1.0)
    rig.cell.reset()
    assert rig.cell.state is CellState.STOPPED


def test_setup_runs_the_recovery_program_when_power_is_off(rig):
    """An e-stop between a servo time-out and its recovery leaves the arm without power:
    the next set-up's move to safe is refused, so it runs the recovery program first."""
    rig.cell.start()
    rig.tick()
    since = len(rig.hal.jobs)
    fail(rig.hal, "robot", "move_safe", ServoTimeout("robot power is off"))
    rig.tick()
    assert rig.cell.state is CellState.STARTING
    pending(rig.hal, "robot", "recover").succeed()
    rig.tick()
    pending(rig.hal, "robot", "move_safe").succeed()
    rig.tick()
    assert rig.cell.state is CellState.STARTING
    assert [m for m in rig.hal.methods()[since - 1:] if m.startswith("robot.")] == [
        "robot.move_safe", "robot.recover", "robot.move_safe"]


def test_cleanup_failure_ends_in_fault(rig):
    rig.start()
    rig.cell.stop()
    for _ in range(4):               # the first try and three more after 1, 2 and 4 s
        rig.tick()
        fail(rig.hal, "horizontal", "stop", ConveyorFault("no answer"))
        assert rig.cell.state is CellState.STOPPING
        rig.tick(int(4.2 / DT))
    assert rig.cell.state is CellState.FAULT
    assert rig.cell.fault_reason.startswith("clean-up failed")


def test_cleanup_runs_the_recovery_program_when_power_is_off(rig):
    """A stop between a servo time-out and its recovery: the move to safe is refused with
    power off, so clean-up runs the recovery program first, then moves, and stops."""
    rig.start()
    rig.cell.stop()
    since = len(rig.hal.jobs)
    rig.tick()
    pending(rig.hal, "horizontal", "stop").succeed()
    pending(rig.hal, "incline", "stop").succeed()
    rig.tick()
    pending(rig.hal, "io", "set").succeed()
    rig.tick()
    fail(rig.hal, "robot", "move_safe", ServoTimeout("robot power is off"))
    rig.tick()
    pending(rig.hal, "robot", "recover").succeed()
    rig.tick()
    pending(rig.hal, "robot", "move_safe").succeed()
    rig.drive_until(CellState.STOPPED, max_s=1.0)
    assert [m for m in rig.hal.methods()[since:] if m.startswith("robot.")] == [
        "robot.move_safe", "robot.recover", "robot.move_safe"]


def test_a_restart_after_a_drift_fault_watches_the_encoders_afresh(rig):
    """The drift watch's streak of verdicts past the limit does not outlive the fault it
    raised: the operator's reset and start build the feeding trees anew (a new watch,
    its streak 0) and the set-up anchors the sync again at rest."""
    from feeder_bt.behaviours.adjust import CheckDrift

    def drift_leaf() -> CheckDrift:
        (leaf,) = [n for n in rig.cell.nodes() if isinstance(n, CheckDrift)]
        return leaf
    rig.start()
    rig.tick(2)
    old = drift_leaf()
    old.watch._over = old.watch.window - 1        # one verdict short of the fault
    rig.cell.board.set(FAULTS.ESCALATE, "belt encoders disagree (test)")
    rig.tick()
    rig.drive_until(CellState.FAULT, max_s=1.0)
    rig.cell.reset()
    rig.hal.conveyors["horizontal"].count = 7_000
    rig.start()
    new = drift_leaf()
    assert new is not old and new.watch is not old.watch and new.watch._over == 0
    assert rig.cell.encoder.reference[0] == 7_000    # anchored again at the restart
