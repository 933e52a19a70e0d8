"""The AnyFeeder driver and its emulator: the emulator refuses what the manual
says the feeder refuses, the driver works a simulated plate through it, and a servo error
is reported in one line with the manual's words and recovered by reset and init.
Loopback only; every wait is for a condition, with a generous time-out."""

from __future__ import annotations

import dataclasses
import socket
import time

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.core.clock import RealClock
from feeder_bt.core.errors import CommsLost, PlateFault
from feeder_bt.emulators.anyfeeder import AnyFeederEmulator
from feeder_bt.hal.anyfeeder.driver import AnyFeeder
from feeder_bt.hal.anyfeeder.protocol import ProtocolError, parse_command, parse_reply
from feeder_bt.sim.realtime import Plant

LONG = 30.0


def _plant(quick: bool):
    scenario, cell = load_scenario("scenarios/plate_lenses.yaml")
    if quick:
        cell = dataclasses.replace(cell, plate=dataclasses.replace(cell.plate, **QUICK))
    p = Plant(scenario, cell, seed=1).start()
    yield p
    p.stop()


# A plate whose actions take a tenth of the cell's times: what the protocol and the driver
# answer does not depend on how long an action runs (the replies come at its end, and the
# parts move at its end: hal/sim/plate.py), only the real seconds waited for them do.
QUICK = {"init_s": 0.2, "rep_s": 0.035, "settle_s": 0.03}


@pytest.fixture
def plant():
    """The cell's plate, its times as the cell file gives them (a command while busy
    arrives well inside the 2 s init)."""
    yield from _plant(quick=False)


@pytest.fixture
def quick_plant():
    yield from _plant(quick=True)


def emulator(plant, **kw) -> AnyFeederEmulator:
    return AnyFeederEmulator(plant, **kw).start()


class Raw:
    """A client that sends lines and waits for n reply lines."""

    def __init__(self, port: int) -> None:
        self.s = socket.create_connection(("127.0.0.1", port), timeout=LONG)
        self.buf = b""

    def ask(self, line: str, n: int) -> list[str]:
        self.s.sendall(line.encode() + b"\r")
        return self.read(n)

    def read(self, n: int) -> list[str]:
        out: list[str] = []
        deadline = time.monotonic() + LONG
        while len(out) < n and time.monotonic() < deadline:
            while b"\r" in self.buf and len(out) < n:
                line, self.buf = self.buf.split(b"\r", 1)
                out.append(line.decode())
            if len(out) < n:
                self.buf += self.s.recv(64)
        return out


def wait(job, timeout: float = LONG):
    deadline = time.monotonic() + timeout
    while not job.done and time.monotonic() < deadline:
        time.sleep(0.01)
    assert job.done, job
    return job


def driver(plant, emu) -> AnyFeeder:
    spec = dataclasses.replace(plant.cell.plate, url=f"socket://127.0.0.1:{emu.port}")
    return AnyFeeder(spec, RealClock())


# ------------------------------------------------------------------ the protocol

def test_the_syntax_of_the_guide():
    assert parse_command("x=1").execute == 1
    c = parse_command("ab[3]=2 x=3")
    assert (c.param, c.value, c.execute) == (3, 2, 3)
    assert parse_command("ab[4]=5").execute is None
    for bad in ("X=1", "x=", "ab[3]=2x=3", "ab[3]=2 x=4", "x=1 ", "feed", ""):
        with pytest.raises(ProtocolError):
            parse_command(bad)
    assert parse_reply("m13").describe().startswith("m13: Motor 1 servo error")


# ------------------------------------------------------------------ the emulator refuses

def test_bad_syntax_is_an_invalid_command(plant):
    emu = emulator(plant)
    try:
        raw = Raw(emu.port)
        assert raw.ask("X=1", 2) == ["m12", "m22"]             # case sensitive
        assert raw.ask("ab[1]=11 x=1", 2) == ["m12", "m22"]    # turns 1...10
        assert raw.ask("x=99", 2) == ["m16", "m26"]            # not yet initialised
    finally:
        emu.stop()


def test_a_command_before_init_is_refused(quick_plant):
    plant = quick_plant
    emu = emulator(plant)
    try:
        raw = Raw(emu.port)
        assert raw.ask("x=1", 2) == ["m16", "m26"]
        assert raw.ask(f"x={plant.cell.plate.commands.init}", 4) == ["m11", "m21", "m20", "m10"]
        assert raw.ask("x=1", 4) == ["m11", "m21", "m20", "m10"]
    finally:
        emu.stop()


def test_a_command_while_busy_is_refused(plant):
    emu = emulator(plant)
    try:
        raw = Raw(emu.port)
        init = plant.cell.plate.commands.init
        raw.s.sendall(f"x={init}\rx=1\r".encode())      # the second while homing
        assert raw.read(4) == ["m11", "m21", "m12", "m22"]
        assert raw.read(2) == ["m20", "m10"]
        assert emu.lines == [f"x={init}", "x=1"]
    finally:
        emu.stop()


# ------------------------------------------------------------------ the driver

def test_the_driver_works_the_simulated_plate(quick_plant):
    plant = quick_plant
    emu = emulator(plant)
    feeder = driver(plant, emu)
    try:
        assert wait(feeder.init()).ok and feeder.status().initialised
        assert wait(feeder.dispense(3)).ok
        with plant.lock:
            on_plate = len(plant.world.on_horizontal)
            before = [r["x_mm"] for r in plant.world.truth()]
        assert on_plate > 0
        assert wait(feeder.feed(1, 3)).ok
        with plant.lock:
            after = [r["x_mm"] for r in plant.world.truth()]
        assert sum(after) > sum(before)
        assert wait(feeder.flip(1)).ok and wait(feeder.purge(10)).ok
        assert "> ab[1]=3 x=1" in feeder.log and "< m10" in feeder.log
        assert not feeder.status().busy and feeder.status().fault is None
    finally:
        feeder.close()
        emu.stop()


def test_a_servo_error_is_one_line_and_reset_and_init_recover_it(quick_plant):
    plant = quick_plant
    emu = emulator(plant, servo_error_at=2)
    feeder = driver(plant, emu)
    try:
        assert wait(feeder.init()).ok
        assert wait(feeder.dispense(1)).ok
        job = wait(feeder.feed(1, 1))
        assert isinstance(job.error, PlateFault)
        msg = str(job.error)
        assert "\n" not in msg and "m13" in msg and "servo error" in msg
        assert "must be reset before operation can continue" in msg
        err = wait(feeder.feed(1, 1)).error                  # refused until reset
        assert "m17" in str(err) and "error state" in str(err)
        assert wait(feeder.reset()).ok
        assert "m16" in str(wait(feeder.feed(1, 1)).error)   # homed again after a reset
        assert wait(feeder.init()).ok and wait(feeder.feed(1, 1)).ok
    finally:
        feeder.close()
        emu.stop()


def test_a_fault_plan_ends_the_matching_action_with_a_servo_error(quick_plant):
    """A fault plan's ``servo_timeout`` for controller ``plate`` (how a whole emulated run
    injects one): the second action ends ``m13``; a kind the emulator cannot act on is
    refused when it is built, not ignored."""
    from feeder_bt.emulators.faults import FaultPlan
    plan = FaultPlan()
    plan.add("servo_timeout", "plate", "", nth=2)
    emu = emulator(quick_plant, faults=plan)
    feeder = driver(quick_plant, emu)
    try:
        assert wait(feeder.init()).ok and wait(feeder.dispense(1)).ok
        assert "m13" in str(wait(feeder.feed(1, 1)).error)
        assert [kind for ctrl, kind, _ in plan.log if ctrl == "plate"] == ["servo_timeout"]
    finally:
        feeder.close()
        emu.stop()
    bad = FaultPlan()
    bad.add("drop", "plate")
    with pytest.raises(ValueError, match="cannot inject 'drop'"):
        AnyFeederEmulator(quick_plant, faults=bad)


def test_no_feeder_is_a_lost_link():
    scenario, cell = load_scenario("scenarios/plate_lenses.yaml")
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                                   # nothing listens there now
    spec = dataclasses.replace(cell.plate, url=f"socket://127.0.0.1:{port}")
    feeder = AnyFeeder(spec, RealClock())
    try:
        assert isinstance(wait(feeder.init()).error, CommsLost)
    finally:
        feeder.close()


def test_feeder_emulate_plate_serves_the_feeder_on_loopback(capsys):
    import re
    import threading

    from feeder_bt.cli.main import build_parser
    args = build_parser().parse_args(["emulate", "plate", "--port", "0"])
    stop = threading.Event()
    t = threading.Thread(target=args.handler, args=(args, stop), daemon=True)
    t.start()
    out, port = "", None
    deadline = time.monotonic() + LONG
    while port is None and time.monotonic() < deadline:
        out += capsys.readouterr().out
        m = re.search(r"anyfeeder emulator: socket://127\.0\.0\.1:(\d+)", out)
        port = int(m.group(1)) if m else None
        time.sleep(0.02)
    try:
        assert port is not None, out
        assert Raw(port).ask("x=1", 2) == ["m16", "m26"]
    finally:
        stop.set()
        t.join(LONG)
    assert not t.is_alive()
