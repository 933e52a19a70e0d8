"""The V+ line protocol (vplus/PROTOCOL.md): encoding, reply parsing, error mapping, and the
client's behaviour on garbage and dropped links — against small scripted servers."""

from __future__ import annotations

import socket
import threading

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feeder_bt.core.errors import (
    CommsLost,
    EnvelopeError,
    HalError,
    MissedGrab,
    PowerOff,
    ServoTimeout,
)
from feeder_bt.hal.adept import protocol as P
from feeder_bt.hal.adept.client import Backoff, LineSocket, ServerClient
from feeder_bt.hal.adept.protocol import ProtocolError, VplusError
from feeder_bt.hal.interfaces import Held, Pose

# the scripted servers answer at once: these only bound a hung test on a loaded machine
TIMEOUT_S = 10.0
WAIT_S = 30.0
PICK = P.command("motion", "PICK")
WHERE = P.command("position", "WHERE")
HOLDING = P.command("motion", "HOLDING")
PLACE = P.command("motion", "PLACE")


# ---------------------------------------------------------------------------- requests
def test_encode_request_formats_numbers_and_flags():
    line = P.encode_request("motion", "PICK", 17, 812.4, 301.5, -33.25, 8012345, True,
                            0.0, 0.0, 1.5, 90.0)
    assert line == "PICK 17 812.4 301.5 -33.25 8012345 1 0 0 1.5 90\n"
    assert P.encode_request("motion", "SAFE") == "SAFE\n"
    assert P.encode_request("io", "SET", 2, False) == "SET 2 0\n"
    assert P.encode_request("motion", "SPEED", -0.0001) == "SPEED 0\n"


def test_encode_request_checks_arity_and_values():
    with pytest.raises(ProtocolError, match="PLACE takes 4 arguments"):
        P.encode_request("motion", "PLACE", 1.0, 2.0)
    with pytest.raises(ProtocolError, match="non-finite"):
        P.encode_request("motion", "MOVE", float("nan"), 0.0, 0.0, 0.0)
    with pytest.raises(KeyError):
        P.encode_request("position", "PICK")


def test_every_socket_has_hello_and_unique_verbs():
    for name, table in P.COMMANDS.items():
        verbs = [c.verb for c in table]
        assert "HELLO" in verbs, name
        assert len(verbs) == len(set(verbs)), name


# ---------------------------------------------------------------------------- replies
def test_ok_replies_decode():
    assert P.decode_pick(P.parse_reply("OK 17 871.25\r\n", PICK)) == (17, 871.25)
    assert P.decode_where(P.parse_reply("OK 1370 -150 0.000 12.5", WHERE)) == \
        Pose(1370.0, -150.0, 0.0, 12.5)
    assert P.decode_flag(P.parse_reply(b"OK 1\n", HOLDING), "HOLDING") is True
    assert P.parse_reply("OK", PLACE) == []
    assert P.decode_belt(P.parse_reply("OK -8388608", P.command("position", "BELT"))) == -8388608


@pytest.mark.parametrize("line,cls", [
    ("ERR -1007 *Motor stalled*", ServoTimeout),
    ("ERR -1003 *Time-out nulling errors*", ServoTimeout),
    # power lost to an e-stop or a guard: a person's, never a software recovery's
    ("ERR -604 *Robot power off*", PowerOff),
    ("ERR -9007 *E-stop input active*", PowerOff),
    ("ERR -1006 *Soft envelope error*", ServoTimeout),
    ("ERR -610 *Location out of range*", EnvelopeError),
    ("ERR -9004 *Outside belt window*", EnvelopeError),
    ("ERR -9003 *Nothing gripped*", MissedGrab),
    ("ERR -9001 *Unknown request*", VplusError),
    ("ERR -9005 *Request rejected*", VplusError),
    # unknown numbers: classified by their words, or passed through as VplusError
    ("ERR -1099 *Motor stalled* Mtr 2", ServoTimeout),
    ("ERR -777 *Location out of range* Jt 3", EnvelopeError),
    ("ERR -555 *Something else entirely*", VplusError),
])
def test_err_replies_map_to_typed_errors_with_code_and_text(line, cls):
    with pytest.raises(cls) as info:
        P.parse_reply(line, PICK)
    err = info.value
    assert type(err) is cls
    code, _, text = line[4:].partition(" ")
    assert err.code == int(code) and err.text == text
    assert code in str(err) and "PICK" in str(err)


@pytest.mark.parametrize("line,why", [
    ("", "empty"),
    ("   \r\n", "empty"),
    ("OK", "expected 2 values"),
    ("OK 17", "expected 2 values"),
    ("OK 17 871.25 9", "expected 2 values"),
    ("OK seventeen 871.25", "id is not an integer"),
    ("OK 17 nan", "not finite"),
    ("OK 17 1e999", "not finite"),
    ("ok 17 871.25", "neither OK nor ERR"),
    ("ERR", "without a code"),
    ("ERR abc *x*", "not an integer"),
    ("ERR 1007 *Motor stalled*", "negative"),
    ("\x00\x01\x02", "garbled"),
    ("OK 17 871.25" + "0" * 300, "longer than"),
    (b"OK \xff\xfe 1", "not ASCII"),
])
def test_garbage_replies_raise_protocol_error(line, why):
    with pytest.raises(ProtocolError, match=why):
        P.decode_pick(P.parse_reply(line, PICK))


def test_held_and_poll_replies_decode():
    HELD = P.command("motion", "HELD")
    assert P.decode_held(P.parse_reply("OK 17 0\r\n", HELD)) == Held(17, False, None)
    assert P.decode_held(P.parse_reply("OK 0 17", HELD)) == Held(None, False, 17)
    assert P.decode_held(P.parse_reply("OK -1 9", HELD)) == Held(None, True, 9)
    assert P.decode_held(P.parse_reply("OK 0 0", HELD)).empty
    for bad in ("OK -2 0", "OK 1 -1", "OK x 0", "OK 1"):
        with pytest.raises(ProtocolError):
            P.decode_held(P.parse_reply(bad, HELD))
    POLL = P.command("position", "POLL")
    assert P.decode_poll(P.parse_reply("OK 1 2 3 4 -8388608", POLL)) == \
        (Pose(1.0, 2.0, 3.0, 4.0), -8388608)
    assert P.encode_request("motion", "RECOVER", False) == "RECOVER 0\n"
    assert P.wrap_robot(-(1 << 23) - 1) == (1 << 23) - 1


def test_notify_lines():
    assert P.parse_notify("IN 1001 1\r\n") == (1001, True)
    assert P.parse_notify(b"IN 1003 0") == (1003, False)
    for bad in ("IN 1001", "IN 1001 2", "OUT 2 1", "IN x 1", ""):
        with pytest.raises(ProtocolError):
            P.parse_notify(bad)


def test_signal_numbering_round_trips():
    assert P.signal_of(1, True) == 1001 and P.signal_of(2, False) == 2
    assert P.bit_of(1001) == (1, True) and P.bit_of(2) == (2, False)
    assert P.bit_of(2005) == (2005, False)
    assert P.signal_of(1003, True) == 1003          # a cell that already gives V+ numbers


_words = st.one_of(
    st.sampled_from(["OK", "ERR", "ok", "IN", "-1007", "17", "1", "0", "nan", "*Motor",
                     "stalled*", "-9003", "871.25", "1e5", "-", "+", "inf", ""]),
    st.text(max_size=12),
    st.integers().map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)


@settings(max_examples=400, deadline=None, derandomize=True, database=None)
@given(st.lists(_words, max_size=6).map(" ".join), st.sampled_from(
    [c for table in P.COMMANDS.values() for c in table]))
def test_reply_parser_never_fails_untyped(line, cmd):
    """Whatever arrives, the parser returns values or raises a HalError — never an
    IndexError, ValueError or UnicodeError."""
    try:
        values = P.parse_reply(line, cmd)
    except HalError:
        return
    assert len(values) == len(cmd.reply)
    decoders = {"PICK": P.decode_pick, "WHERE": P.decode_where, "BELT": P.decode_belt,
                "HELLO": P.decode_hello,
                "SIG": lambda v: P.decode_flag(v, "SIG"),
                "HOLDING": lambda v: P.decode_flag(v, "HOLDING"),
                "HELD": P.decode_held, "POLL": P.decode_poll}
    if cmd.verb in decoders:
        try:
            decoders[cmd.verb](values)
        except HalError:
            pass


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(st.binary(max_size=40))
def test_reply_parser_on_raw_bytes(raw):
    try:
        P.parse_reply(raw, PICK)
    except HalError:
        pass
    try:
        P.parse_notify(raw)
    except HalError:
        pass


# ---------------------------------------------------------------------------- client
class ScriptedServer:
    """A one-port server that answers each request line with the next scripted reply
    (bytes sent as they are), or closes the connection for ``None``."""

    def __init__(self, replies: list[bytes | None]) -> None:
        self.replies = list(replies)
        self.requests: list[str] = []
        self.connections = 0
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(1)
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            self.connections += 1
            with conn:
                conn.settimeout(0.1)
                buf = b""
                while not self.stop.is_set():
                    try:
                        chunk = conn.recv(1024)
                    except TimeoutError:
                        continue
                    except OSError:
                        break
                    if not chunk:
                        break
                    buf += chunk
                    closed = False
                    while b"\n" in buf:
                        line, _, buf = buf.partition(b"\n")
                        self.requests.append(line.decode())
                        reply = self.replies.pop(0) if self.replies else b"OK\r\n"
                        if reply is None:
                            closed = True
                            break
                        conn.sendall(reply)
                    if closed:
                        break

    def close(self) -> None:
        self.stop.set()
        self.sock.close()
        self.thread.join(timeout=2)


@pytest.fixture
def server():
    servers: list[ScriptedServer] = []

    def make(replies):
        servers.append(ScriptedServer(replies))
        return servers[-1]

    yield make
    for s in servers:
        s.close()


def test_garbage_reply_raises_protocol_error_and_the_client_resyncs(server):
    srv = server([b"OK 17 871.25 extra\r\n", b"OK 18 900.5\r\n"])
    link = LineSocket("motion", "127.0.0.1", srv.port, timeout_s=TIMEOUT_S)
    try:
        with pytest.raises(ProtocolError, match="expected 2 values") as got:
            link.request("motion", "PICK", 17, 1.0, 2.0, 3.0, 4, True, 0.0, 0.0, 0.0, 0.0)
        # a garbled reply is a lost reply: the trees' link recovery asks what is held
        assert isinstance(got.value, CommsLost) and got.value.kind == "comms_lost"
        assert not link.connected                    # dropped: can't trust the stream
        values = link.request("motion", "PICK", 18, 1.0, 2.0, 3.0, 4, True, 0.0, 0.0, 0.0, 0.0)
        assert P.decode_pick(values) == (18, 900.5)
        assert srv.connections == 2
    finally:
        link.close()


def test_overlong_reply_is_a_protocol_error(server):
    srv = server([b"OK " + b"9" * 1000 + b"\r\n"])
    link = LineSocket("position", "127.0.0.1", srv.port, timeout_s=TIMEOUT_S)
    try:
        with pytest.raises(CommsLost, match="longer than"):      # a flood: the link is
            link.request("position", "BELT")                      # dropped, as if cut
    finally:
        link.close()


def test_dropped_socket_is_comms_lost_then_reconnects(server):
    srv = server([None, b"OK 1\r\n"])
    client = ServerClient("motion", "127.0.0.1", srv.port, timeout_s=TIMEOUT_S)
    try:
        fut = client.submit("HOLDING")
        with pytest.raises(CommsLost, match="closed by the controller"):
            fut.result(timeout=WAIT_S)
        backoff = client.link.backoff
        assert backoff.next_try > 0 and backoff.delay == 0.2   # the first back-off is armed
        assert client.submit("HOLDING").result(timeout=WAIT_S) == ["1"]
        assert backoff.next_try == 0.0 and backoff.delay == 0.1   # connected: reset
        assert srv.connections == 2
    finally:
        client.close()


def test_silent_server_times_out_as_comms_lost(server):
    srv = server([b"OK"])                               # no line end: never a whole reply
    link = LineSocket("io", "127.0.0.1", srv.port, timeout_s=0.3)
    try:
        with pytest.raises(CommsLost, match="no reply to SIG within the time-out"):
            link.request("io", "SIG", 1001)
        assert not link.connected                     # a late reply would answer the next
        assert srv.requests == ["SIG 1001"]
    finally:
        link.close()


def test_no_server_is_comms_lost_after_backing_off():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()                                           # nothing listens there
    link = LineSocket("motion", "127.0.0.1", port, timeout_s=0.5)
    with pytest.raises(CommsLost, match="127.0.0.1"):
        link.request("motion", "HELLO")
    assert not link.connected and link.connects == 0
    assert link.backoff.delay > 0.1                     # it backed off between attempts
    link.close()


def test_backoff_doubles_to_two_seconds_and_resets():
    b = Backoff()
    delays = []
    for _ in range(8):
        delays.append(b.delay)
        b.failed(0.0)
    assert delays[:6] == [0.1, 0.2, 0.4, 0.8, 1.6, 2.0]
    assert max(delays) == 2.0
    b.succeeded()
    assert b.delay == 0.1 and b.next_try == 0.0
    b.dropped(10.0)
    assert b.next_try == pytest.approx(10.1)


# ---------------------------------------------------------------------------- cell settings
def _cell_with(tmp_path, adept: str):
    from pathlib import Path

    from feeder_bt.config import load_scenario
    root = Path(__file__).resolve().parents[2]
    cell = tmp_path / "cell.yaml"
    cell.write_text((root / "cells" / "sim.yaml").read_text() + "\nadept:\n" + adept)
    return load_scenario(str(root / "scenarios" / "lenses.yaml"), str(cell))[1].adept


def test_adept_safety_and_polling_settings_have_safe_defaults_and_are_checked(tmp_path):
    from feeder_bt.core.errors import ConfigError
    from feeder_bt.core.model import AdeptSpec

    spec = AdeptSpec()
    assert spec.recover_power_on is False            # the operator turns arm power on
    assert spec.belt_direction == "forward" and spec.poll_hz == 50.0
    got = _cell_with(tmp_path, "  recover_power_on: true\n  belt_direction: reverse\n"
                               "  poll_hz: 20\n")
    assert (got.recover_power_on, got.belt_direction, got.poll_hz) == (True, "reverse", 20)
    with pytest.raises(ConfigError, match="belt_direction: must be one of forward, reverse"):
        _cell_with(tmp_path, "  belt_direction: backwards\n")
    with pytest.raises(ConfigError, match="poll_hz"):
        _cell_with(tmp_path, "  poll_hz: 0\n")


def test_a_pick_needs_a_positive_part_id():
    from feeder_bt.core.clock import RealClock
    from feeder_bt.hal.adept.robot import AdeptRobot
    from feeder_bt.hal.interfaces import PickTarget

    client = ServerClient("motion", "127.0.0.1", 9, timeout_s=0.2)   # never connected
    try:
        job = AdeptRobot(client, RealClock(), 1.0, 1.0).pick(PickTarget(0, 1.0, 2.0, 0.0, 0))
        assert job.done and "positive id" in str(job.error)
        assert client.link.connects == 0
    finally:
        client.close()


def test_a_motions_deadline_grows_as_the_robot_slows():
    """``motion_timeout_s`` is the longest motion at full speed: a lost reply (a half-open
    link) is found that soon, and a robot run at 25 % gets four times as long."""
    from concurrent.futures import ThreadPoolExecutor

    from feeder_bt.core.clock import RealClock
    from feeder_bt.hal.adept.robot import AdeptRobot

    class _Motion:
        worker = ThreadPoolExecutor(1)

        def call(self, verb, *args, timeout=None, on_timeout=None):
            self.last = (verb, timeout)
            return []

    motion = _Motion()
    robot = AdeptRobot(motion, RealClock(), motion_timeout_s=6.0, timeout_s=2.0)  # type: ignore[arg-type]
    assert robot.motion_deadline_s() == 6.0
    robot.set_speed(25.0)
    motion.worker.shutdown(wait=True)          # the SPEED request has run
    assert motion.last == ("SPEED", 2.0)
    assert robot.motion_deadline_s() == 24.0
    robot._call("SAFE")
    assert robot.motion.last == ("SAFE", 24.0)
