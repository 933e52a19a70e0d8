"""The Galil driver against the Galil emulator on loopback (and over a pty): every command
the HAL uses, typed errors from TC1, unsolicited output split from replies, the card's
programs downloaded and running, lost links and reconnection."""

from __future__ import annotations

import socket
import time
from pathlib import Path

import pytest

from feeder_bt.core.clock import RealClock
from feeder_bt.core.errors import CommsLost, ConveyorFault, HalError
from feeder_bt.core.jobs import JobState
from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.emulators.galil.emulator import GalilEmulator, serve
from feeder_bt.hal.galil import DownloadError, GalilController, GalilError
from feeder_bt.hal.galil.driver import PROGRAMS_DIR
from feeder_bt.hal.galil.protocol import DistanceEvent, InputsEvent, Message, read_programs
from feeder_bt.hal.interfaces import IoChange
from tests.support.galil_fixtures import (
    JAM_BIT,
    TIMEOUT_S,
    WAIT_S,
    plant_and_emulator,
    rig,
    wait_job,
    wait_until,
)

CPM = 20.0


def ok(job):
    wait_job(job)
    assert job.state is JobState.SUCCEEDED, (job, job.error)
    return job.result


def drain(q) -> list:
    out = []
    while not q.empty():
        out.append(q.get()[0])
    return out


# ---------------------------------------------------------------------------- connect


def test_connect_downloads_and_starts_the_programs():
    with rig() as r:
        cmds = r.connect_commands
        assert cmds[:5] == ["EO 0", "CW 1", "WH", "CF A", "MG _XQ0"]   # EO 0 first (finding 8)
        assert "HX" not in cmds                          # no HX of every thread (finding 6)
        dl = cmds.index("DL")
        assert all(c.startswith("MG _XQ") for c in cmds[4:12])
        # the cell file's safety settings, before the programs and before anything moves:
        # ER 5 mm at 20 counts/mm, TL 5 V with no peak above it, OE 1, limit switches and
        # latch active low, inputs 5-8 general, the abort input leaves our programs running
        assert cmds[12:dl] == ["ER 100,100", "TL 5,5", "TK 0,0", "OE 1,1", "CN -1,-1,-1,0,1"]
        assert {"DSTEP=100", "DAXIS=1", f"WDMS={r.cell.galil.watchdog_s * 1000:.0f}", "WDAXES=3", "INBANKS=1", "ERSEEN=0",
                "XQ #INMON,0", "XQ #DIST,1", "XQ #WDOG,2"} <= set(cmds)
        assert not any(c.startswith("SH") for c in cmds)     # no SH without the person
        assert "MG _TI1" not in cmds                          # an 8-input card
        assert r.emu.cw_msb and r.emu.interp.running() == [0, 1, 2]
        assert r.ctl.handle == "A" and r.emu.cf == "A"
        assert r.ctl.connects == 1 and r.ctl.connected
        assert r.ctl.inputs_mask == 0 and r.ctl.outputs_mask == 0
        assert r.ctl.position("B") == 0 and r.ctl.program_errors == []


@pytest.mark.parametrize("name", sorted(p.name for p in PROGRAMS_DIR.glob("*.dmc")))
def test_dl_of_every_program_file(name):
    """Each file of galil_programs/ downloads on its own and the card accepts it."""
    with plant_and_emulator() as (_plant, emu, cell):
        cell.galil.programs = [name]
        ctl = GalilController(cell.galil, RealClock(), PROGRAMS_DIR, counts_per_mm=CPM)
        try:
            assert ctl.ready.result(15.0) is True
            want = {pl.text.upper() for pl in read_programs(PROGRAMS_DIR, [name])
                    if pl.text.startswith("#")}
            assert emu.interp.program is not None
            assert set(emu.interp.program.labels) == want
            assert len(emu.interp.program.lines) == len(read_programs(PROGRAMS_DIR, [name]))
        finally:
            ctl.close()


def test_dl_refuses_an_over_long_line_before_sending(tmp_path: Path):
    (tmp_path / "bad.dmc").write_text("REM fine\n#A\n  MG \"" + "x" * 90 + "\"\nEN\n")
    with plant_and_emulator() as (_plant, emu, cell):
        cell.galil.programs = ["bad.dmc"]
        with pytest.raises(DownloadError) as err:
            GalilController(cell.galil, RealClock(), tmp_path, counts_per_mm=CPM)
        assert f"{tmp_path / 'bad.dmc'}:3:" in str(err.value)
        time.sleep(0.1)
        assert emu.commands == []                  # nothing was sent: not even a connect


# ---------------------------------------------------------------------------- conveyor


def test_jog_change_speed_stop_and_position():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        axis = r.plant.axis("B")
        ok(belt.set_speed(100.0))
        assert belt.speed() == 100.0
        assert axis.commanded == pytest.approx(100.0)
        # JG then BG (the health poll's queries may come between or after them)
        sent = [c for c in r.emu.commands if c.startswith(("JG", "BG"))]
        assert sent[-2:] == ["JG ,2000", "BGB"]
        n = len(r.emu.commands)
        ok(belt.set_speed(150.0))                  # jogging: JG changes speed, no new BG
        assert "JG ,3000" in r.emu.commands[n:] and "BGB" not in r.emu.commands[n:]
        assert axis.commanded == pytest.approx(150.0)
        # acceleration was set from the cell at connect
        assert {"AC ,30000", "DC ,30000"} <= set(r.emu.commands)
        ok(belt.stop())
        assert belt.speed() == 0.0 and "STB" in r.emu.commands
        assert not r.plant.in_motion("B")
        wait_until(lambda: belt.position() == r.plant.position_counts("B"))
        assert belt.position() == r.plant.position_counts("B") > 0
        ok(belt.set_speed(0.0))                    # 0 stops


def test_move_ends_when_bg_reads_zero():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        start = r.plant.position_counts("B")
        job = belt.move(30.0, 200.0)
        assert not job.done                        # returns at once
        ok(job)
        assert {"SPB=4000", "PR ,600", "BGB"} <= set(r.emu.commands)
        assert "MG _BGB" in r.emu.commands
        assert r.plant.position_counts("B") == start + 600
        assert belt.position() == start + 600      # read after the move: exact
        ok(belt.set_speed(50.0))                   # a move while jogging stops first
        ok(belt.move(-10.0, 100.0))
        assert r.plant.position_counts("B") == belt.position()
        assert belt.move(5.0, 0.0).state is JobState.FAILED


def test_a_speed_above_max_mm_s_is_refused_and_nothing_is_sent():
    """As the simulated belt: a failed job naming the conveyor, speed, limit and cell file;
    never a silent clamp, and no JG/SP reaches the card."""
    with rig() as r:
        belt = r.conveyors["horizontal"]
        top = r.cell.conveyors["horizontal"].max_mm_s
        n = len(r.emu.commands)
        job = belt.set_speed(top + 50.0)
        assert job.state is JobState.FAILED        # at once: nothing was queued
        assert isinstance(job.error, HalError)
        assert str(job.error) == (f"horizontal conveyor: {top + 50:g} mm/s commanded, above "
                                  f"its max_mm_s {top:g} ({r.cell.path}); refused")
        assert "\n" not in str(job.error) and "sim.yaml" in str(job.error)
        assert belt.move(10.0, -(top + 1.0)).state is JobState.FAILED
        assert belt.speed() == 0.0
        ok(belt.set_speed(20.0))                   # the worker is FIFO: had the refused
        sent = [c for c in r.emu.commands[n:] if c[:2] in ("JG", "SP", "PR")]
        assert sent == ["JG ,400"]                 # commands been queued, they came first
        assert r.plant.axis("B").commanded == pytest.approx(20.0)


def test_exactly_max_mm_s_is_accepted():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        top = r.cell.conveyors["horizontal"].max_mm_s
        n = len(r.emu.commands)
        ok(belt.set_speed(top))
        assert [c for c in r.emu.commands[n:] if c[:2] in ("JG", "BG")] == [
            f"JG ,{round(top * CPM)}", "BGB"]
        assert belt.speed() == top
        assert r.plant.axis("B").commanded == pytest.approx(top)
        ok(belt.move(-20.0, -top))                 # a move's speed is its magnitude
        assert f"SPB={round(top * CPM)}" in r.emu.commands


def test_shake_returns_to_the_speed_it_had():
    with rig() as r:
        belt = r.conveyors["incline"]
        ok(belt.set_speed(80.0))
        ok(belt.shake(5.0, 2))
        assert [c for c in r.emu.commands if c.startswith("PR")][-4:] == [
            "PR 100", "PR -100", "PR 100", "PR -100"]
        assert belt.speed() == 80.0
        assert r.plant.axis("A").commanded == pytest.approx(80.0)


def test_travelled_and_distance_events():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        q = r.ctl.events()
        job = belt.travelled(20.0)
        time.sleep(0.05)
        assert job.poll() is JobState.RUNNING      # the belt is still
        ok(belt.set_speed(200.0))
        ok(job)
        assert r.plant.position_counts("B") >= 400
        ok(belt.stop())
        events = [e for e in drain(q) if isinstance(e, DistanceEvent)]
        assert len(events) >= 4
        counts = [e.count for e in events]
        assert counts == sorted(counts)
        assert all(b - a >= 100 for a, b in zip(counts, counts[1:], strict=False))
        back = belt.travelled(-5.0)
        ok(belt.move(-10.0, 100.0))
        ok(back)


def test_latch_armed_and_read_at_the_camera_trigger():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        seen = []
        r.plant.on_trigger(lambda t: seen.append(r.plant.position_counts("B", t)))
        ok(belt.set_speed(100.0))
        ok(belt.arm_latch())
        assert "ALB" in r.emu.commands
        reading = belt.read_latch(timeout_s=10.0)
        time.sleep(0.15)
        assert not reading.done                    # _ALB still 1: not tripped
        r.plant.trigger()
        latched = ok(reading)
        assert latched == seen[0] > 0
        assert {"MG _ALB", "MG _RLB"} <= set(r.emu.commands)
        ok(belt.arm_latch())
        job = wait_job(belt.read_latch(timeout_s=0.3))
        assert job.state is JobState.FAILED and isinstance(job.error, HalError)
        assert "not tripped" in str(job.error)


def test_abort_and_servo_off():
    with rig() as r:
        belt = r.conveyors["horizontal"]
        ok(belt.set_speed(100.0))
        ok(belt.abort())
        assert "AB 1" in r.emu.commands
        assert wait_until(lambda: not r.plant.in_motion("B"))
        assert r.emu.interp.running() == [0, 1, 2]  # AB 1 leaves the programs running
        ok(belt.servo(False))
        job = wait_job(belt.set_speed(50.0))
        assert job.state is JobState.FAILED and isinstance(job.error, ConveyorFault)
        assert "motor off" in str(job.error)            # code 20, said as an operator matter
        ok(belt.servo(True))
        ok(belt.set_speed(50.0))


# ---------------------------------------------------------------------------- I/O


def test_outputs_and_input_changes():
    with rig() as r:
        io = r.io
        assert io.get("backlight") is False
        ok(io.set("backlight", True))
        assert "SB 1" in r.emu.commands and r.plant.signal("backlight")
        assert io.get("backlight") is True
        ok(io.set("backlight", False))
        assert "CB 1" in r.emu.commands and not r.plant.signal("backlight")
        ok(io.set(1, True))                                        # by Galil bit number
        assert r.plant.signal("backlight") and io.get("backlight")
        ok(io.set("backlight", False))
        assert io.set("nonsense", True).state is JobState.FAILED
        assert io.set(99, True).state is JobState.FAILED
        assert io.set("jam", True).state is JobState.FAILED        # an input
        r.plant.set_signal("jam", True)
        assert wait_until(lambda: io.get("jam"))
        assert io.get(JAM_BIT) is True
        r.plant.set_signal("jam", False)
        assert wait_until(lambda: not io.get("jam"))
        changes: list[IoChange] = io.changes()
        assert [(c.signal, c.value) for c in changes] == [("jam", True), ("jam", False)]
        assert changes[0].t <= changes[1].t and io.changes() == []
        assert r.ctl.inputs_mask == 0
        assert r.emu.function("IN", JAM_BIT) == 0.0


# ---------------------------------------------------------------------------- errors


def test_rejected_command_raises_galil_error_from_tc1():
    with rig() as r:
        err = r.ctl.command("XX").exception(WAIT_S)
        assert isinstance(err, GalilError)
        assert (err.code, err.text, err.command) == (1, "Unrecognized command", "XX")
        assert r.emu.commands[-2:] == ["XX", "TC1"]
        err = r.ctl.command("bg").exception(WAIT_S)     # lower case is not a command
        assert isinstance(err, GalilError) and err.code == 1
        assert r.ctl.command("TPB").result(3).strip() == "0"
        with pytest.raises(HalError):
            r.ctl.ask("TPB")                        # only on the device worker
        assert r.ctl.submit(r.ctl.ask_number, "MG _BGB").result(3) == 0


def test_fault_plan_reject_is_a_typed_error_with_a_plausible_code():
    faults = FaultPlan()
    faults.add("reject", "galil", "BG", nth=1)
    with rig(faults) as r:
        job = wait_job(r.conveyors["horizontal"].set_speed(100.0))
        assert job.state is JobState.FAILED and isinstance(job.error, GalilError)
        assert job.error.code == 22 and "Limit Switch" in job.error.text
        ok(r.conveyors["horizontal"].set_speed(100.0))       # the second BG goes through


def test_unsolicited_bytes_in_the_middle_of_a_reply():
    with rig() as r:
        q = r.ctl.events()
        ok(r.conveyors["horizontal"].move(7.0, 100.0))
        r.emu.inject_into_next_reply("HELLO\r\n")
        assert r.ctl.command("TPB").result(3).strip() == "140"
        assert wait_until(lambda: any(isinstance(e, Message) and e.text == "HELLO"
                                      for e in drain(q)))
        r.emu.inject_into_next_reply("I 004\r\n")
        assert r.ctl.command("MG 1+2*3").result(3).strip() == "9.0000"
        assert wait_until(lambda: r.ctl.inputs_mask == 4)


def test_drop_fault_surfaces_as_comms_lost_and_the_driver_reconnects():
    faults = FaultPlan()
    faults.add("drop", "galil", "TPB", nth=2)
    with rig(faults) as r:
        belt = r.conveyors["horizontal"]
        err = r.ctl.command("TPB").exception(WAIT_S)
        assert isinstance(err, CommsLost) and not isinstance(err, GalilError)
        assert wait_until(lambda: r.ctl.command("TPB").exception(WAIT_S) is None)
        assert r.ctl.connects == 2
        assert r.emu.commands.count("DL") == 2 and r.emu.interp.running() == [0, 1, 2]
        assert "IHA=>-2" in r.emu.commands           # the stale handle freed (finding 5)
        assert r.emu.handles() == {"B": "open"} and r.emu.cf == "B"
        ok(belt.set_speed(100.0))                  # and it works again


def test_server_side_socket_kill_and_stall():
    faults = FaultPlan()
    with rig(faults) as r:
        faults.add("stall", "galil", "TPA", nth=1, stall_s=3600.0)   # until the drop
        # in flight when the server closes the socket: CommsLost at once
        n = r.emu.commands.count("TPA")
        fut = r.ctl.command("TPA")
        assert wait_until(lambda: r.emu.commands.count("TPA") > n)   # in flight, held back
        r.emu.drop_clients()
        err = fut.exception(WAIT_S)
        assert isinstance(err, CommsLost) and "lost" in str(err)
        assert wait_until(lambda: r.ctl.command("TPA").exception(WAIT_S) is None)
        assert r.ctl.connects == 2
        # killed while idle: the next command reconnects on its own
        r.emu.drop_clients()
        assert wait_until(lambda: not r.ctl.connected)
        assert r.ctl.command("TPA").exception(WAIT_S) is None and r.ctl.connects == 3
        # a reply held back past timeout_s is a lost link too: the card stays silent (an
        # hour, or until the link closes), so only the time-out can end the wait, and a
        # short one cannot be tripped by a slow machine
        r.ctl.spec.timeout_s = 1.0
        faults.add("stall", "galil", "TPB", nth=1, stall_s=3600.0)
        err = r.ctl.command("TPB").exception(WAIT_S)
        assert isinstance(err, CommsLost) and "no reply" in str(err)
        r.ctl.spec.timeout_s = TIMEOUT_S
        assert wait_until(lambda: r.ctl.command("TPB").exception(WAIT_S) is None)


class _TestMonotonic:
    """The driver's ``time.monotonic``, moved only by the test: the back-off is judged on
    it, so a slow machine cannot let a back-off run out between two of the test's lines."""

    def __init__(self) -> None:
        self.t = 1000.0

    def monotonic(self) -> float:
        return self.t


def test_reconnect_back_off_until_the_controller_is_there(monkeypatch):
    import feeder_bt.hal.galil.driver as driver_module

    clock = _TestMonotonic()
    monkeypatch.setattr(driver_module, "time", clock)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with plant_and_emulator() as (plant, _emu, cell):
        cell.galil.url = f"socket://127.0.0.1:{port}"
        ctl = GalilController(cell.galil, RealClock(), PROGRAMS_DIR, counts_per_mm=CPM)
        late = None
        try:
            assert isinstance(ctl.ready.exception(WAIT_S), CommsLost)
            assert ctl._backoff == pytest.approx(0.2)    # failed once: 0.1 s, then 0.2 s
            clock.t += 0.05
            err = ctl.command("TPB").exception(WAIT_S)  # within the back-off: refused at once
            assert isinstance(err, CommsLost) and "next attempt in 0.05 s" in str(err)
            assert ctl._backoff == pytest.approx(0.2)    # not tried: no further back-off
            clock.t += 0.1
            assert isinstance(ctl.command("TPB").exception(WAIT_S), CommsLost)  # tried, failed
            assert ctl._backoff == pytest.approx(0.4)
            late = serve(plant, "127.0.0.1", port)
            err = ctl.command("TPB").exception(WAIT_S)   # there now, but 0.2 s to wait
            assert isinstance(err, CommsLost) and "next attempt" in str(err)
            clock.t += 0.25
            assert ctl.command("TPB").exception(WAIT_S) is None
            assert ctl.connects == 1 and late.interp.running() == [0, 1, 2]
        finally:
            ctl.close()
            if late is not None:
                late.stop()


def test_closed_controller_refuses_commands():
    with rig() as r:
        r.ctl.close()
        assert isinstance(r.ctl.command("TPB").exception(1), CommsLost)
        job = wait_job(r.conveyors["horizontal"].set_speed(10.0))
        assert job.state is JobState.FAILED and isinstance(job.error, CommsLost)


# ---------------------------------------------------------------------------- pty


def test_the_same_driver_over_a_pty_serial_port():
    faults = FaultPlan()
    with rig(faults, pty=True) as r:
        assert r.cell.galil.url.startswith("/dev/")
        belt = r.conveyors["horizontal"]
        q = r.ctl.events()
        ok(belt.set_speed(150.0))
        ok(belt.travelled(10.0))
        ok(belt.move(0.0, 100.0))                  # stops the jog, a zero move
        assert any(isinstance(e, DistanceEvent) for e in drain(q))
        r.plant.set_signal("jam", True)
        assert wait_until(lambda: r.io.get("jam"))
        err = r.ctl.command("XX").exception(WAIT_S)
        assert isinstance(err, GalilError) and err.code == 1
        assert belt.position() == r.plant.position_counts("B")
        assert InputsEvent(1 << (JAM_BIT - 1)) in [e for e in drain(q)] or r.io.get("jam")
        # a lost reply on the serial line: CommsLost, then the port is reopened
        # (the line stays silent: only the time-out ends the wait, so a short one is safe)
        faults.add("drop", "galil", "TPA", nth=1)
        r.ctl.spec.timeout_s = 1.0
        try:
            assert isinstance(r.ctl.command("TPA").exception(WAIT_S), CommsLost)
        finally:
            r.ctl.spec.timeout_s = TIMEOUT_S
        assert wait_until(lambda: r.ctl.command("TPA").exception(WAIT_S) is None)
        assert r.ctl.connects == 2
        ok(belt.set_speed(20.0))


# ---------------------------------------------------------------------------- emulator, raw


def split(data: bytes) -> tuple[bytes, bytes]:
    """(solicited, unsolicited with the top bit stripped)."""
    return (bytes(b for b in data if not b & 0x80), bytes(b & 0x7F for b in data if b & 0x80))


class RawClient:
    """A bare socket to the emulator, to check the wire format itself."""

    def __init__(self, emu: GalilEmulator) -> None:
        self.sock = socket.create_connection(("127.0.0.1", emu.port), timeout=WAIT_S)

    def send(self, data: bytes, replies: int = 1, lines: int = 0) -> bytes:
        """Send, then read until ``replies`` replies and ``lines`` unsolicited lines came."""
        self.sock.sendall(data)
        buf = b""
        end = time.monotonic() + WAIT_S                 # bounds a hung test only
        while time.monotonic() < end:
            solicited, unsolicited = split(buf)
            if (solicited.count(b":") + solicited.count(b"?") >= replies
                    and unsolicited.count(b"\n") >= lines):
                break
            buf += self.sock.recv(4096)
        return buf

    def close(self) -> None:
        self.sock.close()


def test_emulator_wire_format():
    with plant_and_emulator() as (_plant, emu, _cell):
        c = RawClient(emu)
        try:
            assert c.send(b"TPB\r") == b" 0\r\n:"
            assert c.send(b"TP\r") == b" 0, 0\r\n:"
            assert c.send(b"TPA;TPB\r", replies=2) == b" 0\r\n: 0\r\n:"
            assert c.send(b"\r") == b":"
            assert c.send(b"xyz\r") == b"?"
            assert c.send(b"TC1\r") == b"1 Unrecognized command\r\n:"
            assert c.send(b"TC\r") == b"1\r\n:"
            assert c.send(b"MG 1+2*3\r") == b" 9.0000\r\n:"
            assert c.send(b'MG "a:b", 5 {F2.1}\r') == b"a:b 05.0\r\n:"
            assert c.send(b"V1=7\r") == b":"
            assert c.send(b"V1=?\r") == b" 7.0000\r\n:"
            assert c.send(b"SPB=2000\r") == b":"
            assert c.send(b"SPB=?\r") == b" 2000\r\n:"
            assert c.send(b"PR ,500\r") == b":"
            assert c.send(b"PR ?\r") == b" 0, 500\r\n:"
            assert c.send(b"BGB\r") == b"?"                     # motor off
            assert c.send(b"TC1\r") == b"20 Begin not valid with motor off\r\n:"
            assert c.send(b"CW 0\r").startswith(b"Galil Motion Control DMC-21x3")
            assert c.send(b"TI\r") == b" 0\r\n:"
            assert c.send(b"SB 1\r") == b":" and _plant.signal("backlight")
            assert c.send(b"MG @OUT[1], _OP0\r") == b" 1.0000 1.0000\r\n:"
            assert c.send(b"CB 1\r") == b":" and not _plant.signal("backlight")
            assert c.send(b"SB 99\r") == b"?"
            assert c.send(b"EO 0\r") == b":"
            assert c.send(b"SHAB\r") == b":"
            assert c.send(b"JG ,1000;BGB\r", replies=2) == b"::"
            assert c.send(b"MG _BGB\r") == b" 1.0000\r\n:"
            assert wait_until(lambda: _plant.velocity_counts("B") > 999)
            assert c.send(b"TVB\r") == b" 1000\r\n:"
            assert c.send(b"PR ,5;BGB\r", replies=2) == b":?"              # still jogging
            assert c.send(b"MOB\r") == b"?"                                # moving
            assert c.send(b"STB\r") == b":"
            assert wait_until(lambda: c.send(b"MG _BGB\r") == b" 0.0000\r\n:")
            assert c.send(b"ALB;MG _ALB\r", replies=2) == b": 1.0000\r\n:"
            _plant.trigger()
            latched = _plant.position_counts("B")
            assert c.send(b"MG _ALB\r") == b" 0.0000\r\n:"
            assert c.send(b"RLB\r") == f" {latched}\r\n:".encode()
            assert c.send(b"JG 500;BGA;AB\r", replies=3) == b":::"
            assert wait_until(lambda: not _plant.in_motion("A"))
            assert c.send(b"MOAB;BGA\r", replies=2) == b":?"
            # DL: limits checked by the card too
            assert c.send(b"DL\r#A\r" + b"X" * 81 + b"\r\\") == b"?"
            assert c.send(b"TC1\r") == b"60 Download error - line too long or too many lines\r\n:"
            assert c.send(b"DL\r#A\rMG \"hi\"\rEN\r\\") == b":"
            assert c.send(b"CW 1\r") == b":"
            assert c.send(b"WH\r") == b"IHA\r\n:"
            assert c.send(b"CF A\r") == b":"          # program output to this handle
            got = c.send(b"XQ #A,2\r", lines=1)
            assert split(got) == (b":", b"hi\r\n")         # in either order
            assert c.send(b"DL\r#B\rWT 1000\rEN\r\\") == b":"
            assert c.send(b"XQ #B\r") == b":"
            assert c.send(b"DL\r") == b"?"                      # a program runs
            assert c.send(b"TC1\r") == b"17 ED, BN and DL not valid while program running\r\n:"
            assert c.send(b"HX\r") == b":"
            assert c.send(b"DL\r#C\rXX 1\rEN\r\\") == b":"
            got = c.send(b"XQ #C\r", lines=1)
            assert split(got) == (b":", b"002 XX 1?\r\n")
            assert c.send(b"TC1\r") == b"1 Unrecognized command\r\n:"
        finally:
            c.close()


def test_handles_run_out_and_ih_frees_them():
    """Finding 5: a DMC has a fixed number of Ethernet handles; a further connection is
    reset. A dropped link's handle stays taken (stale) until IH frees it."""
    with plant_and_emulator() as (_plant, emu, _cell):
        emu.max_handles = 2
        a, b = RawClient(emu), RawClient(emu)
        assert a.send(b"WH\r") == b"IHA\r\n:" and b.send(b"WH\r") == b"IHB\r\n:"
        c = RawClient(emu)
        c.sock.sendall(b"TPB\r")
        assert c.sock.recv(10) == b""              # every handle taken: refused
        c.close()
        emu.drop_clients()                          # cable pulled: both handles stale
        assert wait_until(lambda: emu.handles() == {"A": "stale", "B": "stale"})
        d = RawClient(emu)
        d.sock.sendall(b"TPB\r")
        assert d.sock.recv(10) == b""              # still refused: nobody freed them
        d.close()
        emu.execute("NO")                           # (a command from the serial side)
        emu._local.link = None
        assert emu.execute("IHA=>-2") == ""
        e = RawClient(emu)
        assert e.send(b"WH\r") == b"IHA\r\n:"
        assert e.send(b"IHN=>-2\r") == b":"        # every other handle
        assert emu.handles() == {"A": "open"}
        for x in (a, b, e):
            x.close()


def test_program_messages_only_to_the_handle_cf_names():
    """Finding 3: without CF the messages of #INMON never reach a TCP host."""
    with plant_and_emulator() as (_plant, emu, _cell):
        c = RawClient(emu)
        try:
            assert c.send(b"DL\r#A\rMG \"hi\"\rEN\r\\") == b":"
            assert c.send(b"CW 1\r") == b":"
            assert c.send(b"XQ #A\r") == b":"
            c.sock.settimeout(0.3)
            with pytest.raises(TimeoutError):
                c.sock.recv(10)                     # lost: CF names no handle of ours
            c.sock.settimeout(WAIT_S)
            assert c.send(b"CF A\r") == b":"
            got = c.send(b"XQ #A\r", lines=1)
            assert split(got) == (b":", b"hi\r\n")
        finally:
            c.close()
