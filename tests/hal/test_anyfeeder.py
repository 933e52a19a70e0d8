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
        assert wait(feeder.reset()).ok                       # and homes (anyfeeder_connector)
        assert wait(feeder.feed(1, 1)).ok
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


def test_a_silent_line_is_a_lost_link_not_a_stuck_feeder(quick_plant):
    """A pulled serial cable answers nothing, not even the action's busy codes: the
    driver says the line is down (a lost link the trees wait out), not that the feeder is
    stuck, and the port opened afresh owes nothing of the action it never heard end."""
    from feeder_bt.emulators.linkproxy import LinkProxy
    plant = quick_plant
    emu = emulator(plant)
    proxy = LinkProxy(emu.port)
    spec = dataclasses.replace(plant.cell.plate, url=f"socket://127.0.0.1:{proxy.port}",
                               timeout_s=0.5)
    feeder = AnyFeeder(spec, RealClock())
    try:
        assert wait(feeder.init()).ok
        proxy.silence()
        err = wait(feeder.flip(1)).error
        assert isinstance(err, CommsLost) and "line is down" in str(err), err
        proxy.restore()
        job = wait(feeder.dispense(1))
        assert job.ok, job.error                # nothing owed: the next action runs
        proxy.silence()                         # a short pull: the command is lost,
        job = feeder.flip(1)                    # the line is back before its deadline
        time.sleep(0.2)
        proxy.restore()
        err = wait(job).error
        assert isinstance(err, CommsLost) and "answers idle" in str(err), (err, list(feeder.log)[-8:])
        assert wait(feeder.flip(1)).ok
    finally:
        feeder.close()
        proxy.close()
        emu.stop()


def test_feeder_emulate_plate_serves_the_feeder_on_loopback(capsys):
    import io
    import re
    import threading

    from feeder_bt.cli.main import build_parser
    args = build_parser().parse_args(["emulate", "plate", "--port", "0"])
    stop = threading.Event()
    t = threading.Thread(target=args.handler, args=(args, stop, io.StringIO("")), daemon=True)
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


# ------------------------------------------------------------------ as real feeders speak
# Findings against feeders that speak as SHOP4CF/anyfeeder_connector expects (echo first),
# report their motors apart, send a late m28: docs/plate-feeders.md.

STANDARD = ["m11", "m21", "m20", "m10"]


def test_the_emulator_takes_what_the_manual_allows(quick_plant):
    emu = emulator(quick_plant)
    try:
        raw = Raw(emu.port)
        assert raw.ask("ab[8]=2", 0) == []                      # a set: no response
        assert raw.ask("x=16", 4) == STANDARD                   # init
        assert raw.ask("ab[8]=2 x=8", 4) == STANDARD            # heavy dispense
        for p in (17, 18, 19, 20, 21, 22, 23):                  # every speed
            assert raw.ask(f"ab[{p}]=10 x={p}", 4) == STANDARD, p
        assert raw.ask("ab[7]=127 x=7", 4) == STANDARD          # purge 1...127
        assert raw.ask("ab[24]=5 x=24", 2) == ["m12", "m22"]    # not in the manual
        assert raw.ask("ab[17]=11 x=17", 2) == ["m12", "m22"]   # speed 1...10
        raw.s.sendall(b"x=1\r\n")                               # a CR LF client
        assert raw.read(4) == STANDARD
        assert raw.ask("x=2", 4) == STANDARD                    # its next line too
        assert emu.params[17] == 10 and emu.params[8] == 2
    finally:
        emu.stop()


def test_the_echo_is_found_at_connect_and_skipped(quick_plant):
    emu = emulator(quick_plant, echo=True)
    feeder = driver(quick_plant, emu)
    try:
        raw_lines = Raw(emu.port)       # one client at a time: this one waits its turn
        raw_lines.s.close()
        assert wait(feeder.connect()).result["echo"] is True
        assert wait(feeder.init()).ok and wait(feeder.dispense(2)).ok
        assert wait(feeder.feed(1, 2)).ok and wait(feeder.purge(3)).ok
        assert feeder.echo and "< x=16" in feeder.log and feeder.status().fault is None
    finally:
        feeder.close()
        emu.stop()


def _commands_wait_for_both_motors(log: list[str]) -> None:
    """Each command after the probe is written only once both motors have reported
    (done or an error) for the one before."""
    commands = [i for i, line in enumerate(log) if line.startswith("> ") and " x=" in
                line or line.startswith("> x=")]
    for a, b in zip(commands, commands[1:], strict=False):
        between = log[a:b]
        assert any(x in between for x in ("< m10", "< m13", "< m16", "< m17")), between
        assert any(x in between for x in ("< m20", "< m23", "< m26", "< m27", "< m28")), \
            between


def test_an_action_ends_only_when_both_motors_have_reported(quick_plant):
    """Motor 2 reports 0.4 s after motor 1 (``m11``, ``m10``, then ``m21``, ``m20``):
    nothing is written while it is busy, and every action completes."""
    emu = emulator(quick_plant, echo=True, motor_gap_s=0.4)
    feeder = driver(quick_plant, emu)
    try:
        assert wait(feeder.init()).ok
        for job in (feeder.dispense(2), feeder.feed(1, 1), feeder.flip(1), feeder.feed(-1, 1)):
            assert wait(job).ok, job.error
        assert emu.overlaps == 0 and "m12" not in " ".join(feeder.log)
        _commands_wait_for_both_motors(feeder.log)
        assert [name for name, _ in emu.done] == ["init", "dispense", "feed_forward", "flip",
                                                  "feed_backward"]
    finally:
        feeder.close()
        emu.stop()


def test_a_late_no_sync_fails_the_dispense_that_never_happened(quick_plant):
    """Motor 2 never starts (no ``m21``) and says ``m28`` after motor 1's ``m10``: the
    dispense is a fault in the manual's words, nothing was dispensed, and the next action
    is written only after it."""
    plant = quick_plant
    emu = emulator(plant, echo=True, motor_gap_s=0.4, late_error_at=1, late_s=0.4)
    feeder = driver(plant, emu)
    try:
        assert wait(feeder.init()).ok
        with plant.lock:
            before = len(plant.world.on_horizontal)
        err = wait(feeder.dispense(3)).error
        assert isinstance(err, PlateFault) and "m28" in str(err) and "no sync" in str(err)
        with plant.lock:
            assert len(plant.world.on_horizontal) == before
        assert feeder.status().fault is err
        assert wait(feeder.dispense(3)).ok and feeder.status().fault is None
        assert emu.overlaps == 0
        _commands_wait_for_both_motors(feeder.log)
    finally:
        feeder.close()
        emu.stop()


def test_cancelling_a_running_action_stops_it_and_waits_for_the_motors(plant):
    emu = emulator(plant)
    feeder = driver(plant, emu)
    try:
        assert wait(feeder.init()).ok
        job = feeder.feed(1, 6)                         # 2.4 s of motion
        deadline = time.monotonic() + LONG
        while "> ab[1]=6 x=1" not in feeder.log and time.monotonic() < deadline:
            time.sleep(0.01)
        job.cancel()
        assert job.state.value == "cancelled"
        assert wait(feeder.flip(1)).ok                  # written after the motors' end
        assert "> x=15" in feeder.log and emu.overlaps == 0
        assert "x=15" in emu.lines
    finally:
        feeder.close()
        emu.stop()


def test_the_cells_speeds_and_repetitions_are_written_after_init(quick_plant):
    from feeder_bt.core.plate_model import PlateRepetitions, PlateSpeeds
    emu = emulator(quick_plant, echo=True)
    spec = dataclasses.replace(quick_plant.cell.plate, url=f"socket://127.0.0.1:{emu.port}",
                               speeds=PlateSpeeds(feed_forward=5, purge=2, flip=7),
                               repetitions=PlateRepetitions(heavy_dispense=2, purge=64))
    feeder = AnyFeeder(spec, RealClock())
    try:
        assert wait(feeder.init()).ok
        assert feeder.params["ab[17]"]["answer"] == STANDARD and feeder.params["ab[17]"][
            "value"] == 5
        assert feeder.params["ab[8]"] == {"what": "heavy_dispense repetitions", "value": 2,
                                          "answer": []}
        assert (emu.params[17], emu.params[21], emu.params[23]) == (5, 7, 2)
        assert (emu.params[8], emu.params[7]) == (2, 64)
        assert wait(feeder.heavy_dispense(2)).ok and emu.done[-1] == ("heavy_dispense", 2)
    finally:
        feeder.close()
        emu.stop()


def test_a_speed_out_of_range_is_refused_by_the_cell_file(tmp_path):
    import yaml

    from feeder_bt.config import load_cell
    from feeder_bt.core.errors import ConfigError
    root = __import__("pathlib").Path(__file__).resolve().parents[2]
    data = yaml.safe_load((root / "cells" / "sim_plate.yaml").read_text())
    data["plate"]["speeds"] = {"flip": 11}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="speeds.flip"):
        load_cell(tmp_path / "cell.yaml")
    data["plate"]["speeds"] = {"flip": 10}
    data["plate"]["repetitions"] = {"purge": 127}
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    assert load_cell(tmp_path / "cell.yaml").plate.speeds.flip == 10


class Fake:
    """A scripted feeder on loopback: ``answer(line)`` gives the byte chunks to send back,
    each its own send; ``push`` sends unasked."""

    def __init__(self, answer) -> None:
        import threading
        self.answer = answer
        self.got: list[str] = []
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(1)
        self.port = self.sock.getsockname()[1]
        self.conn: socket.socket | None = None
        self.ready = threading.Event()
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        conn, _ = self.sock.accept()
        self.conn = conn
        self.ready.set()
        buf = b""
        while True:
            try:
                data = conn.recv(256)
            except OSError:
                return
            if not data:
                return
            buf += data
            while b"\r" in buf:
                line, buf = buf.split(b"\r", 1)
                self.got.append(line.decode())
                for chunk in self.answer(line.decode()):
                    conn.sendall(chunk)

    def push(self, data: bytes) -> None:
        assert self.ready.wait(LONG) and self.conn is not None
        self.conn.sendall(data)

    def close(self) -> None:
        for s in (self.conn, self.sock):
            if s is not None:
                s.close()


def _fake_driver(fake: Fake, **kw) -> AnyFeeder:
    _, cell = load_scenario("scenarios/plate_lenses.yaml")
    spec = dataclasses.replace(cell.plate, url=f"socket://127.0.0.1:{fake.port}",
                               echo_probe_s=0.2, init_s=0.1, rep_s=0.01, settle_s=0.01,
                               timeout_s=5.0, **kw)
    return AnyFeeder(spec, RealClock())


def _echo_standard(line: str) -> list[bytes]:
    """As anyfeeder_connector's mock answers: the echo, then the four motor codes."""
    if " x=" not in line and not line.startswith("x="):
        return [line.encode() + b"\r"]                      # a set: its echo only
    return [line.encode() + b"\r", b"m10\rm11\rm20\rm21\r"]


def test_a_code_after_both_motors_is_the_actions_not_the_next_ones():
    """``m28`` right after ``m10``/``m20`` (before the line goes quiet) fails the action
    it came after; an unasked code while idle fails the next command, which is not sent."""
    late = {"n": 0}

    def answer(line: str) -> list[bytes]:
        chunks = _echo_standard(line)
        if line.endswith("x=6"):
            late["n"] += 1
            chunks.append(b"m28\r")
        return chunks
    fake = Fake(answer)
    feeder = _fake_driver(fake, quiet_s=0.5)
    try:
        assert wait(feeder.init()).ok and feeder.echo
        err = wait(feeder.dispense(1)).error
        assert isinstance(err, PlateFault) and "late m28" in str(err), err
        assert "(after plate.dispense)" in str(err)
        assert wait(feeder.feed(1, 1)).ok
        fake.push(b"m23\r")                                 # unasked, while idle
        sent = len(fake.got)
        err = wait(feeder.flip(1)).error
        assert "not sent: late m23" in str(err) and "servo error" in str(err)
        assert len(fake.got) == sent                        # the flip was never written
    finally:
        feeder.close()
        fake.close()


def test_a_line_without_cr_or_text_that_is_no_reply_drops_the_link_escaped():
    def answer(line: str) -> list[bytes]:
        if line == "x=16":
            return [b"\x1b[2J" + b"A" * 300]
        if line == "x=1" or line.startswith("ab[1]=1 x=1"):
            return [b"m11\r\x07bell\r"]
        return []
    fake = Fake(answer)
    feeder = _fake_driver(fake)
    try:
        err = wait(feeder.init()).error
        assert isinstance(err, CommsLost) and "256 bytes without <cr>" in str(err)
        assert "\\x1b" in str(err) and "\x1b" not in str(err) and len(str(err)) < 200
    finally:
        feeder.close()
        fake.close()
    fake = Fake(answer)
    feeder = _fake_driver(fake)
    try:
        assert wait(feeder.connect()).ok
        err = wait(feeder.feed(1, 1)).error
        assert isinstance(err, CommsLost) and "not an AnyFeeder reply" in str(err)
        assert "\\x07bell" in str(err) and "\x07" not in str(err)
    finally:
        feeder.close()
        fake.close()
