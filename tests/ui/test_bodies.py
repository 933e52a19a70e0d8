"""What a client may send and what is recorded: malformed and huge bodies are a
one-line 400 (a hypothesis fuzz of request bodies against a real simulated cell behind the
real bridge, derandomized), refusals name no server paths, and failed logins, lock-outs and
refused commands reach the event log, `feeder report` and the run's report.

Helpers (in-process browser, cheap users file) come from uiutil.py."""

from __future__ import annotations

import json
import sqlite3
import string
from concurrent.futures import Future
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder_bt.cli.main import main
from feeder_bt.control.access import BadBody, parse_body
from feeder_bt.control.bridge import Bridge, Command
from feeder_bt.records.eventlog import EventLog
from feeder_bt.ui.server import UiApp
from tests.support.uiutil import Browser, FakeClock, SimRig, make_ui, write_users

# ---------------------------------------------------------------------------- bodies


BAD_BODIES = [
    (b"[" * 30_000 + b"]" * 30_000, "nested too deeply"),
    (b'{"user": "alice", "password": ' + b"9" * 5001 + b"}", "number in the body is too long"),
    (b'{"user": "alice", "password": 1e999999}', "out of range"),
    (b'{"user": NaN}', "NaN is not a JSON number"),
    (b"\xff\xfe", "not valid JSON"),
    (b"[]", "must be a JSON object"),
    (b'{"a": {"b": {"c": {"d": {"e": 1}}}}}', "nested too deeply"),
]


@pytest.mark.parametrize("raw,needle", BAD_BODIES, ids=[n for _, n in BAD_BODIES])
def test_malformed_bodies_are_one_line_400s(tmp_path, capsys, raw, needle):
    ui, rec, clock = make_ui(tmp_path)
    code, body = Browser(ui).call("POST", "/api/login", raw=raw)
    assert code == 400 and needle in body["error"] and "\n" not in body["error"]
    assert "Traceback" not in capsys.readouterr().err


def test_parse_body_bounds_numbers_before_converting_them():
    assert parse_body(b'{"horizontal_mm_s": 180.5, "n": -12}') == {
        "horizontal_mm_s": 180.5, "n": -12}
    with pytest.raises(BadBody, match="too long"):
        parse_body(b'{"x": ' + b"1" * 401 + b"}")
    assert parse_body(b'{"x": "[[[[[["}') == {"x": "[[[[[["}   # brackets in strings: fine


class CellBridge(Bridge):
    """The real bridge to a real simulated cell, pumped as soon as a command comes in."""

    def submit(self, name: str, args: Any, user: str) -> Future:
        fut = super().submit(name, args, user)
        self.pump(force=True)
        return fut


@pytest.fixture(scope="module")
def holder(tmp_path_factory):
    """alice, holding control of a real simulated cell through the real bridge."""
    tmp = tmp_path_factory.mktemp("fuzz")
    rig = SimRig()
    bridge = CellBridge(rig.ops.execute, rig.panel.snapshot)
    ui = UiApp(bridge, write_users(tmp / "users.json"), clock=FakeClock(1000.0))
    ui.record.echo = False
    alice = Browser(ui)
    assert alice.login("alice")[0] == 200
    assert alice.call("POST", "/api/control", {"action": "take"})[0] == 200
    return ui, alice, rig


def test_huge_speeds_and_refused_scenarios_name_no_server_path(holder, capsys):
    ui, alice, rig = holder
    code, body = alice.call("POST", "/api/command",
                            raw=b'{"command": "speeds", "horizontal_mm_s": ' + b"9" * 401 + b"}")
    assert code == 400 and "too long" in body["error"]
    code, body = alice.call("POST", "/api/command",
                            {"command": "speeds", "horizontal_mm_s": "9" * 401})
    assert code in (400, 409) and "\n" not in body["error"]
    code, body = alice.call("POST", "/api/command", {"command": "load", "scenario": "../etc"})
    assert code == 400 and str(Path(__file__).parent.parent.parent) not in body["error"]
    assert "no scenario '../etc' (one of:" in body["error"]
    assert "Traceback" not in capsys.readouterr().err


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False)
    | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                max_size=4),
    max_leaves=12)
COMMAND_BODIES = st.fixed_dictionaries(
    {"command": st.sampled_from(["start", "stop", "pause", "resume", "reset", "speeds",
                                 "load", "adjust", "fly"])},
    optional={"horizontal_mm_s": JSON_VALUES, "incline_pct": JSON_VALUES,
              "robot_speed_pct": JSON_VALUES, "scenario": JSON_VALUES, "engaged": JSON_VALUES,
              "action": JSON_VALUES, "user": JSON_VALUES, "password": JSON_VALUES})
NUMBERS = (st.integers() | st.floats(allow_nan=False) | st.integers(10 ** 30, 10 ** 400)
           | st.text(alphabet="0123456789.e-+", max_size=40) | st.booleans() | st.none())
SCALAR_COMMANDS = st.one_of(
    st.fixed_dictionaries({"command": st.just("speeds")},
                          optional={"horizontal_mm_s": NUMBERS, "incline_pct": NUMBERS,
                                    "robot_speed_pct": NUMBERS}),
    st.fixed_dictionaries({"command": st.just("load"),
                           "scenario": st.text(max_size=30) | st.sampled_from(
                               ["lenses", "squares", "../lenses", "/etc/passwd"])}),
    st.fixed_dictionaries({"command": st.sampled_from(["start", "pause", "resume", "stop",
                                                       "reset", "adjust"])},
                          optional={"engaged": NUMBERS}))
RAW = (SCALAR_COMMANDS.map(lambda d: json.dumps(d).encode())
       | st.binary(max_size=200)
       | st.text(alphabet=string.printable, max_size=200).map(str.encode)
       | COMMAND_BODIES.map(lambda d: json.dumps(d).encode())
       | st.builds(lambda n, c: (c * n).encode(), st.integers(1, 20_000),
                   st.sampled_from(["[", "{", '{"a":', "9", "-", "1e9"])))


@settings(derandomize=True, max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture,
                                 HealthCheck.too_slow])
@given(path=st.sampled_from(["/api/command", "/api/control", "/api/login", "/api/logout"]),
       raw=RAW)
def test_fuzzed_bodies_never_get_a_500(holder, capfd, path, raw):
    ui, alice, rig = holder
    code, body = alice.call("POST", path, raw=raw)
    assert code in (200, 400, 401, 403, 409, 413, 429), (code, body)
    if code != 200:
        assert isinstance(body["error"], str) and "\n" not in body["error"]
        assert "/work" not in body["error"] and "Traceback" not in body["error"]
    if path == "/api/logout" or ui.control.holder is None:     # back in control
        if alice.me()[0] != 200:
            assert alice.login("alice")[0] == 200
        alice.call("POST", "/api/control", {"action": "take"})
    assert "Traceback" not in capfd.readouterr().err


# ---------------------------------------------------------------------------- the event log


def test_failures_lock_outs_and_refusals_reach_the_event_log_and_the_report(tmp_path, capsys):
    rig = SimRig()
    log = EventLog(tmp_path / "feeder.db")
    log.start_run({"scenario": "lenses", "cell": "sim", "seed": 1, "hal": "sim"})
    log.attach(rig.cell)
    bridge = Bridge(rig.ops.execute, rig.panel.snapshot)
    ui = UiApp(bridge, write_users(tmp_path / "users.json"), clock=FakeClock(1000.0))
    ui.record.echo = False
    guesser, bob, alice = Browser(ui, "10.0.0.66"), Browser(ui), Browser(ui)
    codes = [guesser.login("alice", f"guess-{i}")[0] for i in range(5)]
    bob.login("bob")
    alice.login("alice")
    alice.call("POST", "/api/control", {"action": "take"})
    bridge.pump()                                            # the tick thread's turn
    code, _ = bob.call("POST", "/api/command", {"command": "start"})
    assert code == 403
    Browser(ui, host="evil.example").me()
    bridge.pump()
    log.flush()
    assert codes == [401, 401, 401, 429, 429]
    conn = sqlite3.connect(tmp_path / "feeder.db")
    kinds = [k for (k,) in conn.execute("SELECT kind FROM events WHERE kind NOT IN "
                                        "('operator', 'state') ORDER BY rowid")]
    assert kinds.count("login_failed") == 3 and kinds.count("login_locked") == 1
    assert kinds.count("login_refused") == 2
    assert kinds.count("command_refused") == 1 and kinds.count("request_refused") == 1
    data = json.loads(conn.execute("SELECT data FROM events WHERE kind='login_locked'")
                      .fetchone()[0])
    assert data == {"user": "alice", "ip": "10.0.0.66", "by": "name and address",
                    "seconds": 1.0}
    conn.close()
    log.finish(None)
    log.close()
    capsys.readouterr()
    assert main(["report", str(tmp_path / "feeder.db"), "--access"]) == 0
    out = capsys.readouterr().out
    assert ("operator access: 3 failed logins, 1 lock-outs, 2 logins refused while locked, "
            "1 refused commands, 1 refused requests") in out
    assert "login_locked" in out and "10.0.0.66" in out
    assert rig.ops.report()["access"]["login_failed"] == 3
    assert any(m.kind == "login_locked" for m in rig.panel.snapshot()[2])   # the messages


def test_a_flood_is_counted_not_logged_line_by_line(tmp_path):
    ui, rec, clock = make_ui(tmp_path)
    ui.record.budget = 10
    for _ in range(50):
        Browser(ui, host="evil.example").me()
    assert len(rec.kinds("request_refused")) == 10
    clock.t += 61.0
    Browser(ui, host="evil.example").me()
    assert rec.kinds("access_suppressed") == [("-", {"count": 40, "window_s": 60.0})]


def test_unknown_access_event_kinds_are_refused():
    rig = SimRig()
    out = rig.ops.execute(Command("access", {"kind": "state"}, "mallory", Future()))
    assert out.status == 400 and rig.ops.report()["access"] == {}
