"""A Galil link that dies like a cable (no FIN, no RST, nothing arrives) for longer than
the card's watchdog: the card stops the belts, and its message saying so is lost with the
link. After the reconnect the driver reads what happened (the axis stopped, its stop code),
counts the watchdog's stop, resumes the belts it was running, and the conveyor reports no
fault: not a jam, as it did when the stop was read as a stall."""

from __future__ import annotations

from feeder_bt.core.clock import RealClock
from feeder_bt.emulators.linkproxy import LinkProxy
from feeder_bt.hal.galil import make_galil
from tests.support.galil_fixtures import WAIT_S, plant_and_emulator, wait_job, wait_until


def test_a_silent_link_past_the_watchdog_resumes_the_belts_and_is_counted():
    with plant_and_emulator(galil={"watchdog_s": 2.0}) as (plant, emu, cell):
        proxy = LinkProxy(emu.port)
        cell.galil.url = f"socket://127.0.0.1:{proxy.port}"
        cell.galil.timeout_s = 1.0
        ctl, conveyors, _io = make_galil(cell, RealClock())
        belt = conveyors["horizontal"]
        try:
            assert ctl.ready.result(WAIT_S)
            assert wait_job(belt.servo(True)).ok
            assert wait_job(belt.set_speed(100.0)).ok
            assert wait_until(lambda: plant.velocity_counts("B") > 1900)
            proxy.silence()                                  # the cable is pulled
            assert wait_until(lambda: not plant.in_motion("B"))   # the card's watchdog
            assert wait_until(lambda: not ctl.connected)      # the driver gave the link up
            proxy.restore()                                   # plugged in again
            assert wait_until(lambda: ctl.connects >= 2)
            assert wait_until(lambda: plant.velocity_counts("B") > 1900)   # resumed
            assert ctl.watchdog_stops == 1 and ctl.connects - 1 >= 1
            assert belt.fault() is None                       # no jam, no stall
            before = belt.position()
            assert wait_until(lambda: belt.position() - before > 2000)  # 100 mm moved on
        finally:
            ctl.close()
            proxy.close()
