"""Nobody on the network can starve the cell by holding connections. Each test
plays the attacker through the public interface on loopback (idle TCP connections from
many 127.x addresses, ``floodutil.IdleFlood``) and then checks that the rightful user or
robot still gets through. Waits are event-driven with long bounds. The only durations
asserted are bounds under the listeners' first-request deadline (``ConnLimits.header_s``,
10 s), measured around the rightful request alone: a request that got through only once
that deadline had closed the flood's connections, not because idle ones made room for it,
would take longer. The claimed figures (2 s for the dashboard and a robot, 5 s for OPC UA,
1 s for the holder of control's Stop under a flood from her own address) are
benchmarks/flood.py's, measured there and not asserted here: a test must pass on a
busy machine (beside two CPU hogs, /api/me under 5000 idle connections took 2.3 s)."""

from __future__ import annotations

import asyncio
import threading
import time

import pytest

from feeder_bt.control.cell import CellState
from feeder_bt.control.conns import ConnLimits
from feeder_bt.control.ticker import Ticker
from feeder_bt.plant.client import PartClient
from feeder_bt.plant.part_server import PartServer
from tests.support.floodutil import IdleFlood, IdleWebsockets, ReopeningFlood
from tests.support.uiutil import Client, FeederUi, make_users

WAIT_S = 60.0
GOT_THROUGH_S = ConnLimits().header_s      # faster than the deadline could have made room


def _wait(pred, what: str, timeout: float = WAIT_S) -> None:
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_idle_connections_do_not_keep_the_controlling_user_from_stop(tmp_path):
    users = make_users(tmp_path / "users.json", {"alice": "alice-secret-1"})
    ui = FeederUi(tmp_path, users)
    flood = None
    try:
        alice = Client(ui.url)
        assert alice.login("alice", "alice-secret-1")[0] == 200
        assert alice.call("api/control", {"action": "take"})[0] == 200
        assert alice.command("start")[0] == 200
        _wait(lambda: alice.status()["state"] == "RUNNING", "the cell to run")
        port = int(ui.url.rsplit(":", 1)[1].strip("/"))
        flood = IdleFlood(port, 5000, addresses=50)
        assert flood.settle() >= 4000
        t0 = time.monotonic()
        code, me, _ = alice.call("api/me")
        t_me = time.monotonic() - t0
        assert code == 200 and me["user"] == "alice" and me["control"]["state"] == "you"
        t0 = time.monotonic()
        code, body = alice.command("stop")
        t_stop = time.monotonic() - t0
        assert code == 200, body
        _wait(lambda: alice.status()["state"] == "STOPPED", "the cell to stop")
        assert t_me < GOT_THROUGH_S and t_stop < GOT_THROUGH_S, (t_me, t_stop)
        assert flood.still_open() <= 512          # the cap in all held
    finally:
        if flood is not None:
            flood.close()
        ui.kill()
    err = (tmp_path / "stderr.txt").read_text()
    assert "Traceback" not in err
    # refusals are told in summary lines, not one line per connection
    assert len([ln for ln in err.splitlines() if "operator UI:" in ln]) <= 5, err[-2000:]


def _answered(call) -> tuple[int, dict, float]:
    """(status, body, seconds) of one request; status 0 if the connection was refused or
    reset instead of answered."""
    t0 = time.monotonic()
    try:
        code, body = call()[:2]
    except OSError as e:                     # urllib's URLError, a reset: no answer
        code, body = 0, {"error": repr(e)}
    return code, body, time.monotonic() - t0


def holder_rounds(alice: Client, rounds: int) -> list[dict]:
    """``rounds`` times: alice starts the cell, waits for it to run, asks ``/api/me`` and
    stops it; what each answer was and how long it took."""
    out = []
    for _ in range(rounds):
        start = _answered(lambda: alice.command("start"))
        end = time.monotonic() + WAIT_S
        while start[0] == 200 and time.monotonic() < end:
            got = _answered(lambda: alice.call("api/status"))
            if got[0] == 200 and got[1]["status"]["state"] == "RUNNING":
                break
            time.sleep(0.05)
        me = _answered(lambda: alice.call("api/me"))
        stop = _answered(lambda: alice.command("stop"))
        out.append({"start": start[0], "me": me[0], "me_s": me[2],
                    "me_control": me[1].get("control", {}).get("state"),
                    "stop": stop[0], "stop_s": stop[2], "stop_body": stop[1]})
        end = time.monotonic() + WAIT_S
        while time.monotonic() < end:
            got = _answered(lambda: alice.call("api/status"))
            if got[0] == 200 and got[1]["status"]["state"] == "STOPPED":
                break
            time.sleep(0.05)
    return out


def test_a_flood_from_her_own_address_never_keeps_the_holder_of_control_from_stop(
        tmp_path):
    """40 idle connections from 127.0.0.1, opened again as the server closes them, and
    32 idle websockets of bob (signed in, observing): every one of alice's requests is
    answered, her Stop included, and the cell stops each time. (Before: reset 8 of 8
    times, ``refused: over 32 from one address``.)"""
    users = make_users(tmp_path / "users.json", {"alice": "alice-secret-1",
                                                  "bob": "bob-secret-22"})
    ui = FeederUi(tmp_path, users)
    flood = sockets = None
    try:
        alice, bob = Client(ui.url), Client(ui.url)
        assert alice.login("alice", "alice-secret-1")[0] == 200
        assert alice.call("api/control", {"action": "take"})[0] == 200
        assert bob.login("bob", "bob-secret-22")[0] == 200
        sockets = IdleWebsockets(ui.url.replace("http://", "ws://") + "ws", bob.cookie, 32)
        port = int(ui.url.rsplit(":", 1)[1].strip("/"))
        flood = ReopeningFlood(port, 40)
        _wait(lambda: flood.reopened >= 40, "the server to close the flood's extra ones")
        rounds = holder_rounds(alice, 8)
        assert [r["me"] for r in rounds] == [200] * 8, rounds
        assert [r["me_control"] for r in rounds] == ["you"] * 8, rounds
        assert [r["stop"] for r in rounds] == [200] * 8, rounds
        slowest = max(max(r["me_s"], r["stop_s"]) for r in rounds)
        assert slowest < GOT_THROUGH_S, rounds
        assert flood.reopened >= 40 and sockets.reopened + flood.reopened > 40
    finally:
        if flood is not None:
            flood.close()
        if sockets is not None:
            sockets.close()
        ui.kill()
    err = (tmp_path / "stderr.txt").read_text()
    assert "Traceback" not in err


class _ServedCell:
    """The lenses cell fed through a part server on loopback, ticking in real time."""

    def __init__(self, trust=None) -> None:
        from tests.plant.test_part_server import Serving
        self.s = Serving(seed=1)
        self.s.program.kill()
        self.s.start()
        self.s.run(80.0, stop=lambda: len(self.s.cell.ctx.queue) >= 4)
        self.server = PartServer(self.s.desk, "127.0.0.1", 0, trust)
        host, port = self.server.start().split(":")
        self.host, self.port = host, int(port)
        self.done = threading.Event()
        ticker = Ticker(self.s.cell, fast=False)
        self.thread = threading.Thread(target=lambda: ticker.run(
            until=self.s.clock.now() + 600.0, stop=self.done.is_set,
            every=self.s.desk.serve_idle))
        self.thread.start()

    def close(self) -> None:
        self.done.set()
        self.thread.join()
        self.server.close()
        self.s.close()


def test_idle_connections_leave_room_for_a_new_robot(capsys):
    served = _ServedCell()
    flood = IdleFlood(served.port, 1200, addresses=40, net=2)
    try:
        assert flood.settle() >= 1000
        t0 = time.monotonic()
        with PartClient.connect(served.host, served.port) as robot:
            status = robot.status()
            t_first = time.monotonic() - t0
            assert status["state"] == "RUNNING"
            offer = robot.part(wait=10.0)
            assert offer is not None
            robot.release(offer.id)
        assert t_first < GOT_THROUGH_S, t_first
        stats = served.server.server.gate.stats()
        gate = served.server.server.gate   # the silent ones wait in the lobby
        assert stats["open"] <= gate.total + gate.lobby, stats
        assert stats["evicted"] >= 1                 # idle ones made room
    finally:
        flood.close()
        served.close()
    err = capsys.readouterr().err
    assert "Traceback" not in err and len(err.splitlines()) <= 5, err[-2000:]


def test_a_flood_from_the_robots_own_address_leaves_it_room(tmp_path, capsys):
    """40 idle connections from the robot's own address (127.0.0.5), opened again as the
    server closes them: the robot the robots file knows by that address is vouched for
    at connect, never closed for a newcomer, and gets its answers and parts."""
    from feeder_bt.plant.robots import RobotTrust
    from tests.plant.test_robot_trust import Line, _robots_file

    path, _secret, _plain = _robots_file(tmp_path, capsys)
    served = _ServedCell(RobotTrust.load(path))
    flood = ReopeningFlood(served.port, 40, source="127.0.0.5")
    try:
        for _ in range(3):
            t0 = time.monotonic()
            robot = Line(served.host, served.port, "127.0.0.5")
            try:
                assert robot.ask("STATUS").startswith("OK STATUS state=RUNNING")
                took = time.monotonic() - t0
                offer = robot.ask("PART WAIT 10")
                assert offer.startswith("OK PART"), offer
                assert robot.ask(f"RELEASE {offer.split()[2]}").startswith("OK")
            finally:
                robot.close()
            assert took < GOT_THROUGH_S, took
        assert served.server.server.gate.counts["admitted"] >= 40   # the flood was in
    finally:
        flood.close()
        served.close()
    assert "Traceback" not in capsys.readouterr().err


def test_a_silent_flood_from_its_own_address_never_keeps_out_an_anonymous_robot():
    """40 connections from 127.0.0.1 that never send a byte, opened again as the server
    closes them, and an anonymous robot from 127.0.0.1 (no robots file: loopback is
    served), which nothing vouches for before its first line: its STATUS is answered 20
    times of 20. The silent ones wait in the gate's lobby (256 places) and only another
    silent one takes a place there; once it has spoken, none of them can."""
    from tests.plant.test_robot_trust import Line

    served = _ServedCell()
    flood = ReopeningFlood(served.port, 40)
    gate = served.server.server.gate
    answers: list[tuple[str, float]] = []
    try:
        _wait(lambda: gate.counts["admitted"] >= 40, "the flood to be in")
        for _ in range(20):
            t0 = time.monotonic()
            try:
                robot = Line(served.host, served.port)
                try:
                    answer = robot.ask("STATUS")
                finally:
                    robot.close()
            except OSError as e:                   # reset before its line was read
                answer = repr(e)
            answers.append((answer, time.monotonic() - t0))
        got = sum(a.startswith("OK STATUS") for a, _ in answers)
        assert got == 20, f"{got} of 20 answered: {answers}"
        assert max(t for _, t in answers) < GOT_THROUGH_S, answers
        assert gate.counts["evicted"] == 0 and gate.counts["refused"] == 0, gate.stats()
    finally:
        flood.close()
        served.close()


def test_idle_connections_on_opc_ua_leave_room_for_a_client(tmp_path):
    pytest.importorskip("asyncua")
    from tests.plant.test_opcua import LiveCell, _log_in_and_read

    live = LiveCell(tmp_path)
    port = live.port
    flood = IdleFlood(port, 1100, addresses=40, net=3)
    try:
        assert flood.settle() >= 900

        state, took = asyncio.run(_log_in_and_read(live.url))
        assert state == CellState.STOPPED.value and took < GOT_THROUGH_S, (state, took)
        gate = live.ua.gate        # the silent ones wait in the lobby, outside the caps
        assert gate.stats()["open"] <= gate.total + gate.lobby, gate.stats()
    finally:
        flood.close()
        live.close()


def test_opc_ua_wrong_arguments_are_invalid_and_anonymous_attempts_recorded(tmp_path):
    pytest.importorskip("asyncua")
    from asyncua import ua
    from asyncua.ua.uaerrors import BadInvalidArgument, UaError

    from tests.plant.test_opcua import ALICE, LiveCell, cell_node, client

    live = LiveCell(tmp_path)
    try:
        async def go() -> None:
            with pytest.raises(UaError):
                async with client(live.url, None):
                    pass
            async with client(live.url, ALICE) as c:
                idx, node = await cell_node(c)
                await node.call_method(f"{idx}:TakeControl")
                nan = ua.Variant(float("nan"), ua.VariantType.Double)
                for bad in (ua.Variant("fast", ua.VariantType.String),
                            ua.Variant(True, ua.VariantType.Boolean),
                            ua.Variant([1.0, 2.0], ua.VariantType.Double)):
                    with pytest.raises(BadInvalidArgument):
                        await node.call_method(f"{idx}:SetSpeeds", bad, nan, nan)
                await node.call_method(f"{idx}:ReleaseControl")

        asyncio.run(go())
        end = time.monotonic() + WAIT_S           # the access event reaches the tick thread
        while live.ua.ops.report()["access"].get("login_refused", 0) < 1:
            assert time.monotonic() < end, live.ua.ops.report()["access"]
            time.sleep(0.05)
    finally:
        live.close()
