"""From the tick thread to the browsers. The
command bridge (commands run only on the tick thread, snapshots published at most at its
rate) and the websocket sender (coalescing, slow and stuck clients, ended sessions).

Time is stepped (fake clocks) wherever the code lets it be."""

from __future__ import annotations

import asyncio
import json
import threading
from concurrent.futures import Future
from pathlib import Path

import pytest

from feeder_bt.control.bridge import SHUTTING_DOWN, Bridge, Command, Message, Outcome
from feeder_bt.control.users import UsersFile
from feeder_bt.ui import server as ui_server
from tests.support.uiutil import FakeClock

# ---------------------------------------------------------------------- bridge


def make_bridge(log: list, wall: FakeClock | None = None) -> Bridge:
    def execute(cmd: Command) -> Outcome:
        log.append((cmd.name, dict(cmd.args), cmd.user))
        if cmd.name == "boom":
            raise RuntimeError("bug")
        if cmd.name == "bad":
            from feeder_bt.core.errors import FeederError
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


def test_a_failing_snapshot_never_stops_the_cell_or_hangs_a_command(capsys):
    def snapshot():
        raise KeyError("tree")

    b = Bridge(lambda cmd: Outcome.done("ok"), snapshot, wall=FakeClock(0.0))
    fut = b.submit("start", {}, "alice")
    assert b.pump() == 1 and fut.result(0).ok      # answered all the same
    b.pump(force=True)
    assert capsys.readouterr().err.count("status snapshot failed") == 1


# ------------------------------------------------------------------- websocket


WAIT_S = 60.0       # a net against a hung loop only: nothing here is judged by the clock


async def settle(turns: int = 50) -> None:
    """Let every ready task run to its next wait: loop turns, not seconds, so a loaded
    machine changes nothing."""
    for _ in range(turns):
        await asyncio.sleep(0)


class FakeSocket:
    """Stands in for a Starlette WebSocket: records what was sent; a closed ``gate`` holds
    each send until the test opens it (a slow client, without the clock)."""

    def __init__(self, stuck: bool = False, gated: bool = False) -> None:
        self.sent: list[dict] = []
        self.closed: int | None = None
        self.stuck = stuck
        self.gate = asyncio.Event()
        if not gated:
            self.gate.set()
        self.sending = 0

    async def send_text(self, text: str) -> None:
        if self.stuck:
            await asyncio.Event().wait()
        self.sending += 1
        await self.gate.wait()
        self.sent.append(json.loads(text))

    async def close(self, code: int = 1000) -> None:
        self.closed = code


async def _until(cond) -> None:
    """Return once ``cond()`` holds (checked every loop turn)."""
    while not cond():
        await asyncio.sleep(0)


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


def test_a_slow_client_gets_only_the_latest_snapshot(tmp_path, monkeypatch):
    monkeypatch.setattr(ui_server, "SEND_TIMEOUT_S", WAIT_S)
    ui, bridge, session = _ui_with_session(tmp_path)

    async def scenario() -> FakeSocket:
        ws = FakeSocket(gated=True)
        client, task = _connect(ui, ws, session)
        for _ in range(20):                         # 20 snapshots while the first send hangs
            bridge.publish()
            ui.wake_all()
            await settle()
        assert ws.sending == 1 and ws.sent == []
        ws.gate.set()                               # the client catches up
        await asyncio.wait_for(_until(lambda: ws.sent and ws.sent[-1]["status"]["seq"] == 20),
                               WAIT_S)
        await settle()
        task.cancel()
        return ws

    ws = asyncio.run(scenario())
    seqs = [m["status"]["seq"] for m in ws.sent]
    assert seqs == [1, 20]                          # coalesced, and ends on the latest
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
        await asyncio.wait_for(task, WAIT_S)        # the send loop gives up on it and ends
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
        await settle()
        ui.users.remove("alice")                    # `feeder users remove alice`
        ui.wake_all()
        await asyncio.wait_for(task, WAIT_S)
        return ws

    ws = asyncio.run(scenario())
    assert ws.sent[-1] == {"type": "logout"} and ws.closed == 4401
    assert len(ui.sessions) == 0


def test_a_client_hears_of_control_changes_but_never_the_same_thing_twice(tmp_path):
    ui, bridge, session = _ui_with_session(tmp_path)

    async def scenario() -> FakeSocket:
        ws = FakeSocket()
        client, task = _connect(ui, ws, session)
        bridge.publish()
        ui.wake_all()
        await settle()
        ui.wake_all()                               # nothing new: nothing sent
        await settle()
        ui.control.take(session)                    # no new snapshot, but news all the same
        ui.wake_all()
        await settle()
        task.cancel()
        return ws

    ws = asyncio.run(scenario())
    assert [m["session"]["control"]["state"] for m in ws.sent] == ["available", "you"]
    assert [m["status"]["seq"] for m in ws.sent] == [1, 1]
