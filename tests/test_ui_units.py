"""Issue 6, without a browser or a network: the users file and `feeder users`, sessions and
the control token, the failed-login limiter, the command bridge, the operator's commands
on a real simulated cell, the dashboard's snapshot, and the websocket sender's coalescing.

Time is stepped (fake clocks, virtual time) wherever the code lets it be."""

from __future__ import annotations

import asyncio
import io
import json
import os
import re
import shlex
import socket
import stat
import threading
from concurrent.futures import Future
from pathlib import Path

import pytest

from feeder_bt.cell import Cell, CellState
from feeder_bt.cli import build_parser, main
from feeder_bt.clock import SimClock
from feeder_bt.hal.sim.devices import make_sim_hal
from feeder_bt.scenario import load_scenario
from feeder_bt.ticker import Ticker
from feeder_bt.ui import parse_bind
from feeder_bt.ui import server as ui_server
from feeder_bt.ui.bridge import SHUTTING_DOWN, Bridge, Command, Message, Outcome
from feeder_bt.ui.control import Control, LoginLimiter, Sessions
from feeder_bt.ui.operate import CellOps, Limits, parse_speeds
from feeder_bt.ui.status import CellPanel
from feeder_bt.ui.users import (
    UsersError,
    UsersFile,
    hash_password,
    verify_password,
)

ROOT = Path(__file__).resolve().parent.parent
LENSES = ROOT / "scenarios" / "lenses.yaml"


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


# ---------------------------------------------------------------------------- users


def test_hashes_are_salted_scrypt_and_verify():
    a, b = hash_password("correct horse"), hash_password("correct horse")
    assert a != b                                   # a fresh salt each time
    assert a.startswith("scrypt$16384$8$1$") and "correct" not in a
    assert verify_password("correct horse", a) and verify_password("correct horse", b)
    assert not verify_password("correct hors", a)
    assert not verify_password("correct horse", "plain:correct horse")
    assert not verify_password("correct horse", "scrypt$2$1$1$AAAA$AAAA")   # too weak: refused


def test_users_file_keeps_no_password_and_is_private(tmp_path):
    f = UsersFile(tmp_path / "cfg" / "users.json")
    f.add("alice", "alice-secret-1")
    f.add("bob", "alice-secret-1")                  # same password, different hash
    text = f.path.read_text()
    assert "alice-secret-1" not in text
    doc = json.loads(text)
    assert doc["users"]["alice"]["hash"] != doc["users"]["bob"]["hash"]
    assert stat.S_IMODE(os.stat(f.path).st_mode) == 0o600
    assert f.names() == ["alice", "bob"]
    assert f.verify("alice", "alice-secret-1") and not f.verify("alice", "wrong-password")
    assert not f.verify("nobody", "alice-secret-1")
    f.remove("bob")
    assert f.names() == ["alice"]


@pytest.mark.parametrize("call,needle", [
    (lambda f: f.add("alice", "another-pass"), "already exists"),
    (lambda f: f.add("bad name", "long-enough"), "bad user name"),
    (lambda f: f.add("carol", "short"), "too short"),
    (lambda f: f.remove("nobody"), "no user 'nobody'"),
])
def test_users_file_mistakes_are_one_line(tmp_path, call, needle):
    f = UsersFile(tmp_path / "users.json")
    f.add("alice", "alice-secret-1")
    with pytest.raises(UsersError) as e:
        call(f)
    assert needle in str(e.value) and "\n" not in str(e.value) and e.value.exit_code == 2


def test_damaged_users_file_fails_closed(tmp_path, capsys):
    p = tmp_path / "users.json"
    p.write_text('{"format": "feeder_bt users 1", "users": {"alice": ')
    with pytest.raises(UsersError, match=r"users.json:1: not a feeder users file"):
        UsersFile(p).names()
    p.write_text('{"users": {}}')
    with pytest.raises(UsersError, match="not a feeder users file"):
        UsersFile(p).names()
    f = UsersFile(p)
    assert f.load_or_empty() == {} and f.load_or_empty() == {}
    assert capsys.readouterr().err.count("nobody can log in") == 1    # warned once


def test_users_file_is_reread_when_it_changes(tmp_path):
    server_view, cli = UsersFile(tmp_path / "u.json"), UsersFile(tmp_path / "u.json")
    assert not server_view.exists("alice")
    cli.add("alice", "alice-secret-1")
    assert server_view.exists("alice")
    cli.remove("alice")
    assert not server_view.exists("alice")


def test_feeder_users_command(tmp_path, monkeypatch, capsys):
    users = str(tmp_path / "users.json")
    monkeypatch.setattr("sys.stdin", io.StringIO("alice-secret-1\n"))
    assert main(["users", "add", "alice", "--password-stdin", "--users", users]) == 0
    assert "alice-secret-1" not in Path(users).read_text()
    monkeypatch.setattr("sys.stdin", io.StringIO("another-secret\n"))
    assert main(["users", "add", "alice", "--password-stdin", "--users", users]) == 2
    assert "already exists" in capsys.readouterr().err
    monkeypatch.setattr("sys.stdin", io.StringIO("another-secret\n"))
    assert main(["users", "add", "alice", "--replace", "--password-stdin",
                 "--users", users]) == 0
    assert UsersFile(users).verify("alice", "another-secret")
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert main(["users", "add", "bob", "--password-stdin", "--users", users]) == 2
    monkeypatch.setattr("sys.stdin", io.StringIO(""))       # not a terminal, no flag
    assert main(["users", "add", "bob", "--users", users]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert "too short" in err[0] and "--password-stdin" in err[1]
    capsys.readouterr()
    assert main(["users", "list", "--users", users]) == 0
    assert capsys.readouterr().out.split() == ["alice"]
    assert main(["users", "remove", "alice", "--users", users]) == 0
    assert main(["users", "remove", "alice", "--users", users]) == 2
    assert main(["users", "list", "--users", users]) == 0
    assert "no users in" in capsys.readouterr().err


# ---------------------------------------------------------------------------- --ui options


def test_ui_bind_parsing():
    assert parse_bind("127.0.0.1:8080") == ("127.0.0.1", 8080)
    assert parse_bind(":9000") == ("127.0.0.1", 9000)
    assert parse_bind("[::1]:0") == ("::1", 0)
    args = build_parser().parse_args(["run", "x.yaml", "--ui"])
    assert (args.ui, args.start, args.duration) == ("127.0.0.1:8080", None, None)
    args = build_parser().parse_args(["run", "x.yaml", "--ui", "0.0.0.0:81", "--start"])
    assert (args.ui, args.start) == ("0.0.0.0:81", True)
    for bad in ("nope", "host:http", "h:70000"):
        with pytest.raises(SystemExit) as e:
            build_parser().parse_args(["run", "x.yaml", "--ui", bad])
        assert e.value.code == 2


def test_run_ui_refuses_bad_set_ups_in_one_line(tmp_path, capsys):
    empty = tmp_path / "none.json"
    assert main(["run", str(LENSES), "--ui", "127.0.0.1:0", "--users", str(empty),
                 "--no-db", "--view", "none"]) == 2
    assert "no users in" in capsys.readouterr().err
    users = UsersFile(tmp_path / "users.json")
    users.add("alice", "alice-secret-1")
    assert main(["run", str(LENSES), "--ui", "127.0.0.1:0", "--users", str(users.path),
                 "--fast", "--no-db"]) == 2
    assert "drop --fast" in capsys.readouterr().err
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen(1)
        port = busy.getsockname()[1]
        assert main(["run", str(LENSES), "--ui", f"127.0.0.1:{port}", "--users",
                     str(users.path), "--no-db", "--view", "none", "--duration", "1"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot listen" in err[0]


# ---------------------------------------------------------------------------- control


def test_sessions_expire_when_idle():
    clock = FakeClock()
    s = Sessions(idle_s=60, clock=clock)
    a, b = s.create("alice"), s.create("alice")
    assert a.token != b.token and len(a.token) >= 40
    assert s.users() == ["alice"] and len(s) == 2
    clock.t += 50
    assert s.get(a.token) is a                      # seen: stays alive
    clock.t += 50
    assert s.get(a.token) is a and s.get(b.token) is None
    assert s.get("forged") is None and s.get(None) is None
    assert s.end(a.token) is a and s.users() == []


def test_one_holder_of_control_at_a_time():
    s, c = Sessions(), Control()
    alice, bob, alice2 = s.create("alice"), s.create("bob"), s.create("alice")
    alice.conns = bob.conns = 1                     # their pages are open
    assert c.state_for(bob) == {"state": "available", "holder": None}
    assert c.refusal(bob) == "refused: take control first (nobody has it)"
    assert c.take(alice) == (True, "you have control")
    assert c.take(alice)[0]                         # taking it again is harmless
    ok, msg = c.take(bob)
    assert not ok and "alice has control" in msg and c.holder is alice
    assert c.release(bob) == (False, "refused: you do not have control")
    assert c.state_for(alice) == {"state": "you", "holder": "alice"}
    assert c.state_for(bob) == {"state": "other", "holder": "alice"}
    assert c.refusal(bob) == "refused: alice has control"
    assert not c.is_holder(alice2) and "another session" in c.refusal(alice2)
    assert c.release(alice)[0] and c.holder is None
    assert c.take(bob)[0]
    assert not c.drop(alice.token) and c.drop(bob.token) and c.holder is None


def test_failed_logins_are_slowed_more_and_more():
    clock = FakeClock()
    lim = LoginLimiter(free=3, base_s=1.0, max_s=8.0, forget_s=600, clock=clock)
    keys = ("user:alice", "ip:10.0.0.9")
    assert lim.failure(keys) == 0 and lim.failure(keys) == 0    # two free mistakes
    assert lim.locked_for(keys) == 0
    assert lim.failure(keys) == 1.0                 # the third locks for 1 s
    assert lim.locked_for(keys) == 1.0 and lim.locked_for(["user:alice"]) == 1.0
    assert lim.locked_for(["user:bob"]) == 0        # others are not affected
    clock.t += 1.0
    assert lim.locked_for(keys) == 0
    assert lim.failure(keys) == 2.0                 # then 2 s, 4 s, 8 s, capped at 8 s
    clock.t += 2.0
    assert lim.failure(keys) == 4.0
    clock.t += 4.0
    assert lim.failure(keys) == 8.0
    clock.t += 8.0
    assert lim.failure(keys) == 8.0
    clock.t += 8.0
    lim.success(keys)                               # a good password clears the count
    assert lim.failure(keys) == 0
    clock.t += 601                                  # and a long quiet spell forgets it
    assert lim.failure(keys) == 0 and lim.failure(keys) == 0 and lim.failure(keys) == 1.0


def test_one_password_check_in_flight_per_key():
    lim = LoginLimiter()
    assert lim.begin(("user:alice", "ip:1"))
    assert not lim.begin(("user:alice", "ip:2"))
    assert not lim.begin(("user:bob", "ip:1"))
    lim.end(("user:alice", "ip:1"))
    assert lim.begin(("user:alice", "ip:2"))


# ---------------------------------------------------------------------------- bridge


def make_bridge(log: list, wall: FakeClock | None = None) -> Bridge:
    def execute(cmd: Command) -> Outcome:
        log.append((cmd.name, dict(cmd.args), cmd.user))
        if cmd.name == "boom":
            raise RuntimeError("bug")
        if cmd.name == "bad":
            from feeder_bt.errors import FeederError
            raise FeederError("cannot start while RUNNING")
        return Outcome.done(f"{cmd.name} done")

    counter = iter(range(10 ** 6))
    return Bridge(execute, lambda: ({"n": next(counter)}, ((0.0, 1.0, 2),),
                                    (Message(1, 0.0, "state", "x"),)),
                  hz=5.0, wall=wall or FakeClock(0.0))


def test_bridge_runs_commands_only_in_pump_in_order():
    log: list = []
    b = make_bridge(log)
    f1 = b.submit("start", {}, "alice")
    f2 = b.submit("speeds", {"horizontal_mm_s": 180}, "alice")
    assert not f1.done() and log == []              # nothing runs on the caller's thread
    assert b.pump() == 2
    assert [x[0] for x in log] == ["start", "speeds"]
    assert f1.result(0) == Outcome.done("start done") and f2.result(0).ok
    assert b.submit("bad", {}, "a") and b.pump() == 1
    b.submit("boom", {}, "a")
    b.pump()
    assert [x[0] for x in log][-2:] == ["bad", "boom"]


def test_bridge_refusals_and_withdrawn_commands():
    log: list = []
    b = make_bridge(log)
    bad, boom = b.submit("bad", {}, "a"), b.submit("boom", {}, "a")
    withdrawn = b.submit("stop", {}, "a")
    assert withdrawn.cancel()                       # the web side timed out first
    b.pump()
    assert bad.result(0) == Outcome.refused("refused: cannot start while RUNNING", 409)
    assert boom.result(0).status == 500 and "internal error" in boom.result(0).message
    assert "bug" not in boom.result(0).message      # its text (paths...) stays on stderr
    assert [x[0] for x in log] == ["bad", "boom"]   # the withdrawn stop never ran
    queued = b.submit("start", {}, "a")
    b.close()
    assert queued.result(0) == Outcome.refused(SHUTTING_DOWN, 503)
    assert b.submit("start", {}, "a").result(0).status == 503
    b.pump()
    assert [x[0] for x in log] == ["bad", "boom"]


def test_bridge_publishes_at_most_hz_and_after_a_command():
    log: list = []
    wall = FakeClock(0.0)
    b = make_bridge(log, wall)
    woken: list[int] = []
    b.subscribe(lambda: woken.append(1))
    b.pump()
    first = b.latest()
    assert first is not None and first.status == {"n": 0, "seq": 1}
    wall.t = 0.1
    b.pump()
    assert b.latest() is first                      # not due yet: nothing built
    seen: list[int] = []
    b.submit("start", {}, "a").add_done_callback(lambda f: seen.append(b.latest().seq))
    b.pump()
    assert b.latest().seq == 2 and seen == [2]      # shows at once, before the answer
    wall.t = 0.2
    b.pump()
    assert b.latest().seq == 2
    wall.t = 0.31
    b.pump()
    assert b.latest().seq == 3 and len(woken) == 3
    pub = b.latest()
    with pytest.raises(AttributeError):
        pub.seq = 9                                 # frozen: safe to share between threads
    assert isinstance(pub.status_json, str) and isinstance(pub.history, tuple)


def test_bridge_between_real_threads():
    """A web-side thread waits on its future while the tick thread pumps."""
    log: list = []
    b = make_bridge(log)
    results: list[Outcome] = []
    stop = threading.Event()

    def tick_thread() -> None:
        while not stop.is_set():
            b.pump()
            stop.wait(0.001)

    t = threading.Thread(target=tick_thread)
    t.start()
    try:
        futures: list[Future] = [b.submit("speeds", {"i": i}, "u") for i in range(50)]
        results = [f.result(timeout=5) for f in futures]
    finally:
        stop.set()
        t.join()
    assert all(r.ok for r in results)
    assert [x[1]["i"] for x in log] == list(range(50))


# ---------------------------------------------------------------------------- the cell


class SimRig:
    """A real Cell on the simulated HAL in virtual time, with the UI's tick-thread parts."""

    def __init__(self) -> None:
        self.scenario, self.spec = load_scenario(LENSES)
        self.clock = SimClock()
        self.hal = make_sim_hal(self.scenario, self.spec, self.clock, 1)
        self.cell = Cell(self.spec, self.hal, self.clock)
        self.cell.load(self.scenario)
        self.ops = CellOps(self.cell, LENSES.parent, self.scenario.cell_path)
        self.panel = CellPanel(self.cell, self.ops.limits, lambda: sorted(self.ops.scenarios))
        self.ticker = Ticker(self.cell, fast=True)

    def do(self, name: str, **args) -> Outcome:
        return self.ops.execute(Command(name, args, "alice", Future()))

    def run(self, seconds: float) -> None:
        self.ticker.run(until=self.clock.now() + seconds)

    def run_until(self, state: CellState, limit: float = 60.0) -> None:
        self.ticker.run(until=self.clock.now() + limit, stop=lambda: self.cell.state is state)
        assert self.cell.state is state

    def horizontal(self) -> float:
        return self.hal.conveyors["horizontal"].speed()


def test_limits_come_from_the_cell():
    _, spec = load_scenario(LENSES)
    lim = Limits.of(spec)
    assert lim.horizontal_max_mm_s == spec.conveyors["horizontal"].max_mm_s == 400
    cur = {"horizontal_mm_s": 150.0, "incline_pct": 40.0}
    assert parse_speeds({"horizontal_mm_s": "180"}, lim, cur) == {"horizontal_mm_s": 180.0}
    for args, needle in [
        ({"horizontal_mm_s": 401}, "above the horizontal conveyor's max_mm_s 400"),
        ({"horizontal_mm_s": 0}, "must be above 0"),
        ({"horizontal_mm_s": "fast"}, "must be a number"),
        ({"horizontal_mm_s": True}, "must be a number"),
        ({"horizontal_mm_s": float("nan")}, "finite"),
        ({"horizontal_mm_s": int("9" * 401)}, "finite"),        # issue 19: not a 500
        ({"horizontal_mm_s": "9" * 401}, "at most 32 characters"),
        ({"horizontal_mm_s": "1e999"}, "finite"),
        ({"incline_pct": 201}, "0-200 %"),
        ({"incline_pct": -1}, "0-200 %"),
        ({"robot_speed_pct": 0}, "robot speed"),
        ({"robot_speed_pct": 250}, "robot speed"),
        ({"horizontal_mm_s": 300, "incline_pct": 150}, "450 mm/s is above the incline"),
        ({"belt": 3}, "unknown speed 'belt'"),
        ({}, "no speed given"),
    ]:
        with pytest.raises(Exception, match=needle):
            parse_speeds(args, lim, cur)
    with pytest.raises(Exception, match="auto-adjuster may drive"):
        parse_speeds({"incline_pct": 150}, lim, cur, adjuster_max_mm_s=300)


def test_operator_commands_on_the_simulated_cell():
    rig = SimRig()
    cell = rig.cell
    out = rig.do("speeds", horizontal_mm_s=180)
    assert not out.ok and out.status == 409 and "start it first" in out.message
    assert rig.do("resume").status == 409 and cell.state is CellState.STOPPED
    assert rig.do("start").ok and cell.state is CellState.STARTING
    rig.run_until(CellState.RUNNING)
    rig.run(1.0)
    before = rig.horizontal()
    assert before >= 150

    bad = rig.do("speeds", horizontal_mm_s=500)
    assert (bad.ok, bad.status) == (False, 400) and "max_mm_s 400" in bad.message
    rig.run(0.2)
    assert rig.horizontal() in (before, before + 5)  # only the adjuster's own step

    assert rig.do("adjust", engaged=False).ok and not cell.auto_adjust
    assert rig.do("speeds", horizontal_mm_s=173).ok
    rig.run(3.0)                                    # six adjust periods: held, not moved
    assert rig.horizontal() == 173.0
    assert rig.do("adjust", engaged=True).ok
    rig.run(1.1)
    assert rig.horizontal() != 173.0                # the adjuster is back in charge

    assert rig.do("load", scenario="squares").status == 409
    assert rig.do("pause").ok and cell.state is CellState.PAUSED
    rig.run(0.5)
    assert rig.horizontal() == 0.0
    assert rig.do("resume").ok
    assert rig.do("stop").ok
    rig.run_until(CellState.STOPPED)
    assert rig.do("stop").status == 409
    assert rig.do("load", scenario="nope").status == 400
    assert rig.do("load", scenario="squares").ok and cell.scenario.name == "squares"
    assert rig.do("start", now=True).status == 400
    assert rig.do("fly").status == 400

    actions = [a["action"] for a in rig.ops.report()["commands"]]
    assert actions == ["start", "adjust", "speeds", "adjust", "pause", "resume", "stop", "load"]
    assert {"t", "user", "action", "horizontal_mm_s"} <= set(rig.ops.report()["commands"][2])


def test_a_held_adjuster_is_kept_across_a_restart():
    rig = SimRig()
    assert rig.do("adjust", engaged=False).ok
    assert rig.do("start").ok
    rig.run_until(CellState.RUNNING)
    rig.run(3.0)
    assert rig.horizontal() == rig.scenario.present.horizontal_mm_s   # never adjusted


def test_dashboard_snapshot():
    rig = SimRig()
    status, history, messages = rig.panel.snapshot()
    assert status["state"] == "STOPPED" and status["tree"] == "" and status["tree_part"] is None
    assert "lenses" in status["scenarios"] and status["limits"]["horizontal_max_mm_s"] == 400
    json.dumps(status)                              # plain data only
    rig.do("start")
    samples = 0

    def every() -> None:
        nonlocal samples
        samples += 1
        rig.panel.snapshot()

    rig.ticker.run(until=60.0, every=every)
    status, history, messages = rig.panel.snapshot()
    assert status["state"] == "RUNNING" and status["tree_part"] == "feeding"
    assert "[*]" in status["tree"] and "retrieve" in status["tree"]
    assert status["total_fed"] > 0 and status["last_part"]["type"] == "lens"
    assert status["hal"]["horizontal_mm_s"] == rig.horizontal() > 0
    assert status["run_time_s"] == pytest.approx(60.0, abs=0.1)
    assert 55 <= len(history) <= 61                 # one sample per second of clock time
    assert all(b[0] > a[0] for a, b in zip(history, history[1:], strict=False))
    assert history[-1][1] > 0                       # parts/min over the last minute
    kinds = {m.kind for m in messages}
    assert "state" in kinds and "operator" in kinds
    assert not kinds & {"located", "retrieved", "speeds"}
    assert [m.seq for m in messages] == sorted(m.seq for m in messages)


# ---------------------------------------------------------------------------- websocket


class FakeSocket:
    """Stands in for a Starlette WebSocket: records what was sent, as slowly as told."""

    def __init__(self, delay: float = 0.0, stuck: bool = False) -> None:
        self.sent: list[dict] = []
        self.closed: int | None = None
        self.delay, self.stuck = delay, stuck

    async def send_text(self, text: str) -> None:
        if self.stuck:
            await asyncio.Event().wait()
        await asyncio.sleep(self.delay)
        self.sent.append(json.loads(text))

    async def close(self, code: int = 1000) -> None:
        self.closed = code


def _connect(ui, ws, session):
    """A websocket client of ``session`` on ``ui``, its send loop running (in a loop)."""
    client = ui_server._Client(ws, session.token)
    ui.clients.add(client)
    return client, asyncio.create_task(ui._send_loop(client))


def _ui_with_session(tmp_path: Path):
    users = UsersFile(tmp_path / "users.json")
    users.add("alice", "alice-secret-1")
    log: list = []
    bridge = make_bridge(log)
    ui = ui_server.UiApp(bridge, users)
    return ui, bridge, ui.sessions.create("alice", "127.0.0.1", users.secret_of("alice"))


def test_a_slow_client_gets_only_the_latest_snapshot(tmp_path):
    ui, bridge, session = _ui_with_session(tmp_path)

    async def scenario() -> FakeSocket:
        ws = FakeSocket(delay=0.05)
        client, task = _connect(ui, ws, session)
        for _ in range(20):                         # 20 snapshots in 0.1 s
            bridge.publish()
            ui.wake_all()
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.2)
        task.cancel()
        return ws

    ws = asyncio.run(scenario())
    seqs = [m["status"]["seq"] for m in ws.sent]
    assert 1 <= len(seqs) < 10 and seqs[-1] == 20   # coalesced, and ends on the latest
    assert seqs == sorted(set(seqs))                # never the same snapshot twice
    assert ws.sent[0]["session"]["control"]["state"] == "available"
    assert ws.sent[0]["history"] == [[0.0, 1.0, 2]] and ws.sent[0]["messages"][0]["seq"] == 1
    assert all(m["history"] == [] and m["messages"] == [] for m in ws.sent[1:])


def test_a_stuck_client_is_dropped(tmp_path, monkeypatch):
    monkeypatch.setattr(ui_server, "SEND_TIMEOUT_S", 0.1)
    ui, bridge, session = _ui_with_session(tmp_path)

    async def scenario() -> tuple[FakeSocket, bool, bool]:
        ws = FakeSocket(stuck=True)
        client, task = _connect(ui, ws, session)
        bridge.publish()
        ui.wake_all()
        await asyncio.sleep(0.3)
        return ws, client in ui.clients, task.done()

    ws, still_there, ended = asyncio.run(scenario())
    assert not still_there and ended


def test_a_client_whose_session_ends_is_told_and_closed(tmp_path):
    ui, bridge, session = _ui_with_session(tmp_path)

    async def scenario() -> FakeSocket:
        ws = FakeSocket()
        client, task = _connect(ui, ws, session)
        bridge.publish()
        ui.wake_all()
        await asyncio.sleep(0.01)
        ui.users.remove("alice")                    # `feeder users remove alice`
        ui.wake_all()
        await asyncio.wait_for(task, 1.0)
        return ws

    ws = asyncio.run(scenario())
    assert ws.sent[-1] == {"type": "logout"} and ws.closed == 4401
    assert len(ui.sessions) == 0


def test_operator_ui_doc_commands_are_real_commands():
    """docs/operator-ui.md's interactive examples (console blocks: they ask for a password
    or serve until Ctrl-C, so test_docs.py cannot run them) parse with the real parser;
    tests/test_ui_http.py and test_ui_browser.py run the same `feeder run --ui`."""
    doc = (ROOT / "docs" / "operator-ui.md").read_text()
    lines = [line[2:] for block in re.findall(r"```console\n(.*?)```", doc, flags=re.S)
             for line in block.splitlines() if line.startswith("$ feeder ")]
    lines += [line.split("| ", 1)[1] for block in re.findall(r"```sh\n(.*?)```", doc, flags=re.S)
              for line in block.splitlines() if "| feeder " in line]
    assert len(lines) >= 6
    for line in lines:
        args = build_parser().parse_args(shlex.split(line)[1:])
        assert args.handler is not None


def test_ui_report_feed_time_is_the_time_between_starts_and_stops():
    from feeder_bt.run import _FeedSpan

    rig = SimRig()
    span = _FeedSpan(rig.cell)
    assert span.seconds(rig.clock.now()) == 0.0             # never started
    rig.do("start")
    t0 = rig.clock.now()
    rig.run(10.0)
    rig.do("stop")
    t1 = rig.clock.now()
    rig.run_until(CellState.STOPPED)
    rig.run(5.0)                                            # idle: not feeding time
    assert span.seconds(rig.clock.now()) == pytest.approx(t1 - t0)
    stats = rig.cell.stats
    rig.do("start")
    t2 = rig.clock.now()
    rig.run(3.0)
    now = rig.clock.now()
    earlier = (t1 - t0) if rig.cell.stats is stats else 0.0  # the cell kept counting, or not
    assert span.seconds(now) == pytest.approx(earlier + now - t2)


def test_a_failing_snapshot_never_stops_the_cell_or_hangs_a_command(capsys):
    def snapshot():
        raise KeyError("tree")

    b = Bridge(lambda cmd: Outcome.done("ok"), snapshot, wall=FakeClock(0.0))
    fut = b.submit("start", {}, "alice")
    assert b.pump() == 1 and fut.result(0).ok      # answered all the same
    b.pump(force=True)
    assert capsys.readouterr().err.count("status snapshot failed") == 1


def test_a_client_hears_of_control_changes_but_never_the_same_thing_twice(tmp_path):
    ui, bridge, session = _ui_with_session(tmp_path)

    async def scenario() -> FakeSocket:
        ws = FakeSocket()
        client, task = _connect(ui, ws, session)
        bridge.publish()
        ui.wake_all()
        await asyncio.sleep(0.01)
        ui.wake_all()                               # nothing new: nothing sent
        await asyncio.sleep(0.01)
        ui.control.take(session)                    # no new snapshot, but news all the same
        ui.wake_all()
        await asyncio.sleep(0.01)
        task.cancel()
        return ws

    ws = asyncio.run(scenario())
    assert [m["session"]["control"]["state"] for m in ws.sent] == ["available", "you"]
    assert [m["status"]["seq"] for m in ws.sent] == [1, 1]
