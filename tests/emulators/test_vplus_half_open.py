"""A V+ motion link that dies without a FIN (a pulled cable): the driver's keep-alive
finds it within seconds, the V+ server drops the silent client (link.idle) so that the
PC's next connection is served, and requests go through again (how soon is the
beat's and link.idle's business, not this test's: no wall-clock bound here). Before,
the server held the dead client for ever and every new HELLO waited out its time-out."""

from __future__ import annotations

import dataclasses
import time

from feeder_bt.config import load_scenario
from feeder_bt.core.clock import RealClock
from feeder_bt.emulators.adept import AdeptEmulator
from feeder_bt.emulators.linkproxy import LinkProxy
from feeder_bt.hal.adept import AdeptController
from feeder_bt.sim.realtime import Plant
from tests.hal.test_adept_driver import WAIT_S, wait_for


def test_a_half_open_motion_link_is_found_and_the_server_takes_the_new_client():
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    plant = Plant(scenario, cell, seed=1).start()
    emu = AdeptEmulator(plant).start()
    proxy = LinkProxy(emu.ports["motion"])
    p = emu.ports
    spec = dataclasses.replace(cell.adept, host="127.0.0.1", motion_port=proxy.port,
                               position_port=p["position"], io_port=p["io"],
                               notify_port=p["notify"], timeout_s=2.0, motion_timeout_s=20.0)
    ctrl = AdeptController(spec, RealClock(), robot=cell.robot,
                           counts_per_mm=cell.encoder.counts_per_mm)
    motion = ctrl.clients["motion"]
    try:
        assert motion.call("HOLDING") == ["0"]
        before = motion.link.connects
        t0 = time.monotonic()
        proxy.silence()                       # the cable is pulled: no FIN either way
        # the keep-alive's time-out finds it: the driver gives the link up
        assert wait_for(lambda: not motion.link.connected, WAIT_S, "the link given up")
        found_s = time.monotonic() - t0
        proxy.restore()                       # plugged in again; the V+ server still
        #                                       holds the dead client until link.idle
        got = None
        # generous for a loaded machine: the server drops the dead client after link.idle
        # (5 s); with link.idle at 500 s (checked) no request ever goes through
        while got is None and time.monotonic() - t0 < 30.0:
            try:
                got = motion.call("HOLDING")
            except Exception:                 # noqa: BLE001 - refused until the drop
                time.sleep(0.2)
        assert got == ["0"] and motion.link.connects > before, found_s
    finally:
        ctrl.close()
        proxy.close()
        emu.stop()
        plant.stop()
