"""Stops and faults that stop. Against the emulator, which runs the
shipped monitor.dmc: a card thread that cannot be restarted, or an input monitor that no
longer counts its heartbeat, FAULTs the cell and stops the belts within 2 s; no ``SH``
without a person; a reversed encoder trips a small error limit, not the card's default
16384 counts; ``CF`` re-asserted; the watchdog stops only our axes; the automatic
subroutines report once; inputs 9-16 only on a card that has them; e-stop polarity.

Waits are event-driven with generous limits; the 2 s bound is measured on the plant's
clock between the event and its effect, in the soak run only (``-m soak``): the plant's
clock follows the wall clock, which a loaded machine stretches."""

from __future__ import annotations

import dataclasses
import time

import pytest

from feeder_bt.config.loader import load_scenario
from feeder_bt.core.clock import RealClock
from feeder_bt.core.errors import CommsLost, ConveyorFault
from feeder_bt.core.jobs import JobState
from feeder_bt.core.model import IoSignal
from feeder_bt.emulators.galil.axes import _Axis
from feeder_bt.emulators.galil.dmc import Program
from feeder_bt.hal.galil import make_galil
from feeder_bt.hal.galil.startup import MAX_RESTARTS
from feeder_bt.trees import present
from tests.support.galil_fixtures import WAIT_S, plant_and_emulator, rig, wait_job, wait_until
from tests.support.treeutil import bb_get, make_ctx

TICK_S = 0.02                # the tree is ticked at 50 Hz, as a run does


def ok(job):
    wait_job(job)
    assert job.state is JobState.SUCCEEDED, job.error
    return job.result


def _sh(cmds: list[str]) -> list[str]:
    return [c for c in cmds if c.startswith("SH")]


# ---------------------------------------------------------------------------- no SH


def test_connecting_and_reconnecting_sends_no_sh_until_a_person_asks():
    with rig(servo=False) as r:
        belt = r.conveyors["horizontal"]
        assert _sh(r.emu.commands) == [] and not r.emu.axes["B"].servo
        assert "never" in (r.ctl.servo_refused or "")
        job = wait_job(belt.set_speed(50.0))             # nobody asked: the motor is off
        assert job.state is JobState.FAILED and "motor off" in str(job.error)
        r.emu.drop_clients()                              # a reconnect does not SH either
        assert wait_until(lambda: r.ctl.connects >= 2
                          and r.ctl.command("TPB").exception(WAIT_S) is None)
        assert _sh(r.emu.commands) == [] and not r.emu.axes["B"].servo
        ok(belt.servo(True))                              # the person asks
        assert _sh(r.emu.commands) == ["SHB"] and r.emu.axes["B"].servo
        r.emu.drop_clients()
        assert wait_until(lambda: r.ctl.connects >= 3
                          and r.ctl.command("TPB").exception(WAIT_S) is None)
        assert _sh(r.emu.commands) == ["SHB"]             # still the person's one only


# ---------------------------------------------------------------------------- ER, OE


def test_a_reversed_encoder_trips_on_a_small_error():
    """ER from the cell file (5 mm = 100 counts): the first motion after SH with the encoder
    wired reversed builds error at twice the speed; OE turns the motor off and #POSERR
    reports, a few mm into the motion, not at the card's default 16384 counts (8192 counts
    of belt: 410 mm). The emulator looks every 10 ms of the wall clock; the bounds below
    allow a busy machine a second's stall (800 counts of error) and still tell the two."""
    assert _Axis("B").er == 16384                         # the card's power-on error limit
    with rig(servo=False) as r:
        belt = r.conveyors["horizontal"]
        r.emu.reversed_encoders.add("B")
        assert r.emu.axes["B"].er == 100 and r.emu.axes["B"].oe == 1
        ok(belt.servo(True))
        start = r.plant.position_counts("B")
        belt.set_speed(20.0)                              # 400 counts/s
        assert wait_until(lambda: any(k == "POSERR" for k, _, _ in r.ctl.card_events))
        st = r.emu.axes["B"]
        assert not st.servo and st.sc == 8                # off-on-error
        assert 100 < abs(st.te) < 1000                    # tripped past ER, far from 16384
        assert wait_until(lambda: not r.plant.in_motion("B"))
        assert abs(r.plant.position_counts("B") - start) < 600   # under 30 mm of belt
        assert wait_until(lambda: isinstance(belt.fault(), ConveyorFault))
        assert "off-on-error" in str(belt.fault())


def test_automatic_subroutines_report_once_until_the_reset():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        monitor = r.emu.interp._threads[0]
        for _ in range(3):                                # the card enters #POSERR 3 times
            r.emu.trip_position_error("B")
            assert wait_until(lambda: not monitor.pending)
            assert wait_until(lambda: r.emu.interp.variables.get("ERSEEN") == 1)
        assert wait_until(lambda: any(k == "POSERR" for k, _, _ in r.ctl.card_events))
        r.ctl.command("MG _TPB").result(WAIT_S)           # anything sent after is in now
        assert [k for k, _, _ in r.ctl.card_events].count("POSERR") == 1
        assert r.emu.interp.running() == [0, 1, 2]        # RE: back to the input monitor
        ok(belt.servo(True))                              # the operator's reset re-arms
        r.emu.trip_position_error("B")
        assert wait_until(lambda: [k for k, _, _ in r.ctl.card_events].count("POSERR") == 2)


# ---------------------------------------------------------------------------- card faults


def _present_tree(r):
    """The present tree over the rig's real conveyors, on the wall clock."""
    sc, _ = load_scenario("scenarios/lenses.yaml")
    ctx = make_ctx(sc, r.cell)
    ctx = dataclasses.replace(ctx, clock=RealClock())
    ctx.hal.conveyors = r.conveyors
    return ctx, present.build(ctx)


def _tick_until(root, cond, timeout: float = WAIT_S) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        root.tick_once()
        if cond():
            return True
        time.sleep(TICK_S)
    return bool(cond())


def _belts_still(r) -> bool:
    return not r.plant.in_motion("A") and not r.plant.in_motion("B")


# The behaviour is judged in every run; the 2 s bound, measured on the plant's clock (which
# follows the wall clock), only in the soak run: a loaded machine may take longer to notice.
BOUND = pytest.mark.parametrize("bound", [False, pytest.param(True, marks=pytest.mark.soak)],
                                ids=["behaviour", "within-2-s"])


@BOUND
def test_a_card_thread_that_cannot_be_restarted_faults_the_cell_and_stops_the_belts(bound):
    with rig() as r:
        _ctx, root = _present_tree(r)
        assert _tick_until(root, lambda: r.plant.velocity_counts("B") > 0
                           and r.plant.velocity_counts("A") > 0)
        for n in range(1, MAX_RESTARTS + 1):              # killed, restarted, again ...
            r.emu.interp.halt(0)
            assert _tick_until(root, lambda n=n: r.ctl.restarts.get(0) == n
                               and 0 in r.emu.interp.running())
            assert r.ctl.card_fault is None and bb_get("/faults/escalate") is None
        t0 = r.plant.now()
        r.emu.interp.halt(0)                              # ... once too often
        assert _tick_until(root, lambda: bb_get("/faults/escalate") is not None)
        t_fault = r.plant.now()
        assert _tick_until(root, lambda: _belts_still(r))
        t_still = r.plant.now()
        assert t_fault >= t0 and t_still >= t0
        if bound:
            assert t_fault - t0 <= 2.0 and t_still - t0 <= 2.0, (t_fault - t0, t_still - t0)
        reason = bb_get("/faults/escalate")
        assert "cannot be restarted" in reason and "thread 0" in reason
        assert reason.startswith("conveyor controller failed") and "jammed" not in reason
        assert "STAB" in r.emu.commands and "ST" not in r.emu.commands   # our axes only
        # nothing moves until an operator's reset; the reset restarts the thread
        job = wait_job(r.conveyors["horizontal"].set_speed(50.0))
        assert job.state is JobState.FAILED and "card fault" in str(job.error)
        ok(r.conveyors["horizontal"].servo(True))
        assert r.ctl.card_fault is None and 0 in r.emu.interp.running()
        ok(r.conveyors["horizontal"].set_speed(50.0))


@BOUND
def test_a_stuck_input_monitor_is_a_card_fault_that_stops_the_belts(bound):
    """Thread 0 runs but no longer counts its heartbeat (an automatic subroutine that never
    returns would do this): the jam input would go unseen. A 3 s heartbeat (the rig's is
    generous): fifteen health polls, so a loaded machine does not miss a beat."""
    with rig(galil={"heartbeat_s": 3.0}) as r:
        _ctx, root = _present_tree(r)
        assert _tick_until(root, lambda: r.plant.velocity_counts("B") > 0)
        prog = r.emu.interp.program
        r.emu.interp.halt(0)
        r.emu.interp.program = Program.parse(prog.lines + ["#STUCK", "WT 10", "JP #STUCK"])
        r.emu.interp.execute("#STUCK", 0)
        t0 = r.plant.now()
        assert _tick_until(root, lambda: bb_get("/faults/escalate") is not None)
        assert _tick_until(root, lambda: _belts_still(r))
        if bound:
            assert r.plant.now() - t0 <= r.cell.galil.heartbeat_s + 2.0
        assert "heartbeat" in bb_get("/faults/escalate")
        assert _ctx.stats.faults == {"card_fault": 1}     # not a jam, never shaken
        assert 0 in r.emu.interp.running()                # alive, yet a fault


# ---------------------------------------------------------------------------- CF, watchdog


def test_cf_is_asserted_again_by_the_health_poll():
    with rig() as r:
        r.emu.cf = None                                   # a card reset forgets it
        assert wait_until(lambda: r.emu.cf == r.ctl.handle == "A")


def test_the_watchdog_stops_our_axes_only():
    with plant_and_emulator(galil={"watchdog_s": 2.0}) as (plant, emu, cell):
        ctl, conveyors, _io = make_galil(cell, RealClock())
        other = emu._axis("C")                            # an axis of someone else's
        try:
            assert ctl.ready.result(WAIT_S)
            ok(conveyors["horizontal"].servo(True))
            ok(conveyors["horizontal"].set_speed(100.0))
        finally:
            ctl.close()                                   # the host is gone
        assert wait_until(lambda: not plant.in_motion("B"))
        assert emu.axes["B"].sc == 4 and emu.axes["A"].sc == 4
        assert other.sc == 1                              # never stopped: not ours
        assert emu.interp.running() == [0, 1, 2]


def test_a_bare_st_from_the_host_also_ends_the_programs():
    """Why the driver never sends one (Galil command reference, ST)."""
    with rig() as r:
        assert r.emu.execute("ST") == ""
        assert r.emu.interp.running() == []


# ---------------------------------------------------------------------------- inputs


def test_inputs_9_to_16_only_on_a_card_that_has_them():
    with plant_and_emulator() as (_plant, emu, cell):
        assert emu.input_count == 8
        cell.galil.inputs = 16                            # the cell says 16, the card has 8
        ctl, _c, _io = make_galil(cell, RealClock())
        try:
            err = ctl.ready.exception(WAIT_S)
            assert isinstance(err, CommsLost) and "galil.inputs" in str(err)
            assert "_TI1" in str(err)
        finally:
            ctl.close()


def test_an_active_low_estop_reads_pressed_when_its_input_is_low():
    with plant_and_emulator() as (plant, _emu, cell):
        cell.io["estop"] = IoSignal("galil", 4, "in", active="low")
        plant.world.io["estop"] = False
        ctl, _c, io = make_galil(cell, RealClock())
        try:
            assert ctl.ready.result(WAIT_S)
            assert ctl.inputs_mask == 1 << 3 and not io.get("estop")    # released: high
            plant.set_signal("estop", True)
            assert wait_until(lambda: io.get("estop"))
            assert ctl.inputs_mask == 0
        finally:
            ctl.close()


def test_a_wrong_limit_switch_polarity_shows_at_the_first_motion():
    """Switches wired to pull their input low when pressed, the cell file saying high: at
    rest the card sees both limits active and refuses BG (code 22), said at once."""
    with plant_and_emulator() as (_plant, emu, cell):
        cell.galil.limit_switches = "high"
        ctl, conveyors, _io = make_galil(cell, RealClock())
        try:
            assert ctl.ready.result(WAIT_S)
            assert emu.cn[0] == 1                          # CN 1,...: sent from the cell file
            belt = conveyors["horizontal"]
            ok(belt.servo(True))
            job = wait_job(belt.set_speed(50.0))
            assert job.state is JobState.FAILED and getattr(job.error, "code", None) == 22
            cell.galil.limit_switches = "low"              # corrected, and reconnected
            emu.drop_clients()
            assert wait_until(lambda: ctl.connects >= 2 and emu.cn[0] == -1)
            ok(belt.set_speed(50.0))
        finally:
            ctl.close()
