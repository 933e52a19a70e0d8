"""Shared set-up for the Galil tests: a plant, the emulator on it, the driver on that.

Everything runs on 127.0.0.1 (port 0) or a pty, and is stopped in teardown. Waits are
event-driven with generous limits, and the driver's reply time-out is generous too
(``TIMEOUT_S``): the tests must pass on a fully loaded machine.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from serial.urlhandler import protocol_socket

from feeder_bt.config.loader import load_scenario
from feeder_bt.core.clock import RealClock
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CellSpec, IoSignal, SimImperfections
from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.emulators.galil.emulator import GalilEmulator
from feeder_bt.hal.galil import GalilController, GalilConveyor, GalilIO, make_galil
from feeder_bt.hal.galil.driver import PROGRAMS_DIR
from feeder_bt.sim.realtime import Plant

SCENARIO = Path(__file__).resolve().parents[2] / "scenarios" / "lenses.yaml"
JAM_BIT = 3                  # a Galil input added to the cell for the tests
TIMEOUT_S = 10.0             # the driver's reply time-out in the tests (a cell setting)
WAIT_S = 30.0                # how long an event-driven wait may take on a loaded machine
# the card's host watchdog and the #INMON heartbeat (cell settings, 1 s each on a real cell)
# are generous in the tests: a loaded machine that starves the driver's health poll (every
# 0.2 s) or the emulated card's thread for a second must not stop the belts mid-test. A
# test of the watchdog or the heartbeat sets its own (``rig(galil={...})``).
WATCHDOG_S = 10.0
HEARTBEAT_S = 10.0


@contextmanager
def no_reconnect_pause() -> Iterator[None]:
    """pyserial's ``socket://`` close() sleeps 0.3 s "in case of quick reconnects, give the
    server some time" (serial/urlhandler/protocol_socket.py, pyserial 3.5); a rig being
    torn down never reconnects, and the Galil tests' ~46 rigs waited ~14 s for it. Only
    around a teardown's close: a reconnect under test keeps the library's pause."""
    saved = protocol_socket.time
    protocol_socket.time = SimpleNamespace(**{**{k: getattr(time, k) for k in dir(time)
                                                 if not k.startswith("_")},
                                              "sleep": lambda s: None})
    try:
        yield
    finally:
        protocol_socket.time = saved


def wait_until(cond: Callable[[], object], timeout: float = WAIT_S, step: float = 0.005) -> bool:
    """Poll ``cond`` until true or ``timeout`` (wall) seconds; returns the last value."""
    end = time.monotonic() + timeout
    while True:
        value = cond()
        if value or time.monotonic() > end:
            return bool(value)
        time.sleep(step)


def wait_job(job: Job, timeout: float = WAIT_S) -> Job:
    """Poll a job as a tree would, until it ends (or ``timeout``)."""
    wait_until(lambda: job.done, timeout)
    return job


def make_cell(galil: dict[str, object] | None = None) -> tuple[object, CellSpec]:
    """The lenses cell with the test's Galil settings; ``galil`` overrides some of them."""
    sc, cell = load_scenario(SCENARIO)
    # the ideal cell: the tests compare the driver's mm with the emulated axis's, which a
    # simulated encoder scale error (docs/simulator.md) would set 0.1 % apart
    cell.sim = SimImperfections(ideal=True)
    cell.io["jam"] = IoSignal("galil", JAM_BIT, "in")
    cell.galil.timeout_s = TIMEOUT_S
    cell.galil.watchdog_s = WATCHDOG_S
    cell.galil.heartbeat_s = HEARTBEAT_S
    for key, value in (galil or {}).items():
        assert hasattr(cell.galil, key), key
        setattr(cell.galil, key, value)
    return sc, cell


@dataclass
class Rig:
    plant: Plant
    emu: GalilEmulator
    cell: CellSpec
    ctl: GalilController
    conveyors: dict[str, GalilConveyor]
    io: GalilIO
    connect_commands: list[str] | None = None    # what the connect sent, before any SH


@contextmanager
def plant_and_emulator(faults: FaultPlan | None = None, pty: bool = False,
                       galil: dict[str, object] | None = None
                       ) -> Iterator[tuple[Plant, GalilEmulator, CellSpec]]:
    sc, cell = make_cell(galil)
    plant = Plant(sc, cell, seed=1).start()
    emu = GalilEmulator(plant, "127.0.0.1", 0, faults, pty=pty).start()
    try:
        cell.galil.url = emu.pty_path if pty else f"socket://127.0.0.1:{emu.port}"
        yield plant, emu, cell
    finally:
        emu.stop()
        plant.stop()


@contextmanager
def rig(faults: FaultPlan | None = None, pty: bool = False,
        programs_dir: Path = PROGRAMS_DIR, servo: bool = True,
        galil: dict[str, object] | None = None) -> Iterator[Rig]:
    """Plant + emulator + connected driver (conveyors and I/O of the cell). ``servo``: then
    the person turns the motors on (``servo(True)``, as the operator's Start does); the
    driver itself never does. ``galil``: Galil settings to override (``make_cell``)."""
    with plant_and_emulator(faults, pty, galil) as (plant, emu, cell):
        ctl, conveyors, io = make_galil(cell, RealClock(), programs_dir)
        try:
            assert ctl.ready.result(WAIT_S) is True
            r = Rig(plant, emu, cell, ctl, conveyors, io)
            r.connect_commands = list(emu.commands)
            if servo:
                for conv in conveyors.values():
                    job = wait_job(conv.servo(True))
                    assert job.ok, job.error
            yield r
        finally:
            with no_reconnect_pause():
                ctl.close()
