"""The cell as an OPC UA server: an asyncua client reads it and commands it
under the dashboard's rules. The simulated cell runs in real time on a thread here (the
server answers clients in real time); the tests wait for states, never assert durations."""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("asyncua")

from asyncua import Client, ua  # noqa: E402
from asyncua.crypto.cert_gen import setup_self_signed_certificate  # noqa: E402
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256  # noqa: E402
from asyncua.ua.uaerrors import BadUserAccessDenied, UaError  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID  # noqa: E402

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402
from feeder_bt.config import load_scenario  # noqa: E402
from feeder_bt.control.cell import Cell  # noqa: E402
from feeder_bt.control.ticker import Ticker  # noqa: E402
from feeder_bt.control.users import UsersFile  # noqa: E402
from feeder_bt.core.clock import SimClock  # noqa: E402
from feeder_bt.core.errors import FeederError  # noqa: E402
from feeder_bt.plant.opcua import CellUaServer  # noqa: E402
from feeder_bt.plant.options import PlantOptions  # noqa: E402
from feeder_bt.sim.devices import make_sim_hal  # noqa: E402

LENSES = "scenarios/lenses.yaml"
ALICE, BOB = ("alice", "alice-pass-1"), ("bob", "bob-pass-123")
WAIT_S = 60.0          # upper bound on waiting for a state; the tests end when it comes


def make_users(path: Path) -> Path:
    users = UsersFile(path)
    users.add(*ALICE)
    users.add(*BOB)
    return path


class LiveCell:
    """A simulated cell ticking in real time on a thread, served over OPC UA."""

    def __init__(self, tmp: Path) -> None:
        scenario, spec = load_scenario(LENSES)
        self.clock = SimClock()
        self.hal = make_sim_hal(scenario, spec, self.clock, 1)
        self.cell = Cell(spec, self.hal, self.clock)
        self.cell.load(scenario)
        self.pki = tmp / "pki"
        self.ua = CellUaServer(self.cell, PlantOptions(
            opcua="127.0.0.1:0", opcua_users=str(make_users(tmp / "users.json")),
            opcua_insecure=True, opcua_pki=str(self.pki)), LENSES)
        self.url = self.ua.start()
        self.done = threading.Event()
        self.todo: list = []                # callables for the tick thread (the cell's own)
        self.thread = threading.Thread(target=lambda: Ticker(self.cell).run(
            until=3600.0, stop=self.done.is_set, every=self.every))
        self.thread.start()

    @property
    def port(self) -> int:
        """The server's TCP port (``opc.tcp://127.0.0.1:PORT/...``)."""
        return int(self.url.rsplit(":", 1)[1].split("/")[0])

    def every(self) -> None:
        while self.todo:
            self.todo.pop(0)()
        self.ua.pump()

    def close(self) -> None:
        self.done.set()
        self.thread.join()
        self.ua.close()
        self.hal.close()


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    cell = LiveCell(tmp_path_factory.mktemp("opcua"))
    yield cell
    cell.close()


def client(url: str, who: tuple[str, str] | None) -> Client:
    c = Client(url, timeout=20)
    if who is not None:
        c.set_user(who[0])
        c.set_password(who[1])
    return c


async def cell_node(c: Client):
    idx = await c.get_namespace_index("urn:feeder_bt")
    return idx, await c.nodes.objects.get_child(f"{idx}:Cell")


async def read(node, idx: int, *path: str):
    child = await node.get_child([f"{idx}:{p}" for p in path])
    return await child.read_value()


async def wait_state(node, idx: int, *states: str) -> str:
    t_end = time.monotonic() + WAIT_S
    while True:
        state = await read(node, idx, "State")
        if state in states or time.monotonic() > t_end:
            return state
        await asyncio.sleep(0.1)


def test_anonymous_and_wrong_passwords_are_refused(live):
    async def go():
        with pytest.raises(UaError):
            async with client(live.url, None):
                pass
        with pytest.raises(UaError):
            async with client(live.url, ("alice", "not-her-password")):
                pass
        with pytest.raises(UaError):
            async with client(live.url, ("mallory", "alice-pass-1")):
                pass
    asyncio.run(go())


def test_the_controlling_user_starts_and_stops_and_a_second_user_is_refused(live):
    async def go():
        async with client(live.url, ALICE) as alice, client(live.url, BOB) as bob:
            idx, a = await cell_node(alice)
            _, b = await cell_node(bob)
            assert await read(a, idx, "Scenario") == "lenses"
            assert await read(a, idx, "State") == "STOPPED"
            # events: every state change is one
            seen: list[tuple[str, str]] = []

            class Handler:
                def event_notification(self, event):
                    seen.append((event.Kind, event.NewState))

            etype = await alice.nodes.base_event_type.get_child(f"{idx}:CellEventType")
            sub = await alice.create_subscription(50, Handler())
            await sub.subscribe_events(a, etype)
            with pytest.raises(BadUserAccessDenied):          # nobody has control yet
                await a.call_method(f"{idx}:Start")
            assert await a.call_method(f"{idx}:TakeControl") == "you have control"
            assert await read(a, idx, "ControlHolder") in ("alice", "")
            assert "STARTING" in await a.call_method(f"{idx}:Start")
            assert await wait_state(a, idx, "RUNNING") == "RUNNING"
            # bob sees the same cell but may not command it, nor take control
            assert await read(b, idx, "State") == "RUNNING"
            for method in ("Stop", "Pause", "TakeControl"):
                with pytest.raises(BadUserAccessDenied):
                    await b.call_method(f"{idx}:{method}")
            assert await read(b, idx, "Speeds", "HorizontalMmS") == 150.0
            # the controlling user sets a speed; a bad one is refused with the reason
            await a.call_method(f"{idx}:SetSpeeds", ua.Variant(120.0, ua.VariantType.Double),
                                ua.Variant(float("nan"), ua.VariantType.Double),
                                ua.Variant(float("nan"), ua.VariantType.Double))
            t_end = time.monotonic() + WAIT_S
            while await read(a, idx, "Speeds", "HorizontalMmS") != 120.0 \
                    and time.monotonic() < t_end:
                await asyncio.sleep(0.1)
            assert await read(a, idx, "Speeds", "HorizontalMmS") == 120.0
            with pytest.raises(UaError):
                await a.call_method(f"{idx}:SetSpeeds",
                                    ua.Variant(-5.0, ua.VariantType.Double),
                                    ua.Variant(float("nan"), ua.VariantType.Double),
                                    ua.Variant(float("nan"), ua.VariantType.Double))
            # counts are the cell's own
            located = await read(a, idx, "Counters", "Located")
            assert isinstance(located, int) and located >= 0
            assert isinstance(await read(a, idx, "PartsPerMin"), float)
            assert "STOPPING" in await a.call_method(f"{idx}:Stop")
            assert await wait_state(a, idx, "STOPPED") == "STOPPED"
            t_end = time.monotonic() + WAIT_S
            while ("state", "STOPPED") not in seen and time.monotonic() < t_end:
                await asyncio.sleep(0.1)
            assert [s for k, s in seen if k == "state"][-4:] == \
                ["STARTING", "RUNNING", "STOPPING", "STOPPED"]
            assert await a.call_method(f"{idx}:ReleaseControl") == "control released"
            assert "you have control" == await b.call_method(f"{idx}:TakeControl")
            assert await b.call_method(f"{idx}:ReleaseControl") == "control released"
    asyncio.run(go())
    assert live.cell.stats.events          # the commands went through the cell's log
    actions = [(c["user"], c["action"]) for c in live.ua.report()["commands"]]
    assert ("alice", "start") in actions and ("alice", "stop") in actions
    assert not any(user == "bob" and a in ("start", "stop") for user, a in actions)


def test_a_fault_is_an_alarm_until_the_reset(live):
    async def go():
        async with client(live.url, ALICE) as alice:
            idx, a = await cell_node(alice)
            alarms: list[dict] = []

            class Handler:
                def event_notification(self, event):
                    f = event.get_event_props_as_fields_dict()
                    alarms.append({k: f[k].Value for k in ("ActiveState/Id", "Message",
                                                          "ConditionName", "Severity")})

            sub = await alice.create_subscription(50, Handler())
            await sub.subscribe_events(a, ua.ObjectIds.OffNormalAlarmType)
            await a.call_method(f"{idx}:TakeControl")
            await a.call_method(f"{idx}:Start")
            assert await wait_state(a, idx, "RUNNING") == "RUNNING"
            live.todo.append(lambda: live.cell.fault("test: a fault on purpose"))
            assert await wait_state(a, idx, "FAULT") == "FAULT"
            assert await read(a, idx, "Fault") == "test: a fault on purpose"
            with pytest.raises(UaError):                   # not from FAULT: reset first
                await a.call_method(f"{idx}:Start")
            await a.call_method(f"{idx}:Reset")
            assert await wait_state(a, idx, "STOPPED") == "STOPPED"
            t_end = time.monotonic() + WAIT_S
            while len(alarms) < 2 and time.monotonic() < t_end:
                await asyncio.sleep(0.1)
            await a.call_method(f"{idx}:ReleaseControl")
            assert [(x["ActiveState/Id"], x["ConditionName"]) for x in alarms] == \
                [(True, "CellFault"), (False, "CellFault")]
            assert alarms[0]["Message"].Text == "test: a fault on purpose"
            assert alarms[0]["Severity"] > alarms[1]["Severity"]
    asyncio.run(go())


def test_control_goes_with_the_session(live):
    async def go():
        async with client(live.url, ALICE) as alice:
            idx, a = await cell_node(alice)
            await a.call_method(f"{idx}:TakeControl")
        async with client(live.url, BOB) as bob:     # alice's session closed: free again
            idx, b = await cell_node(bob)
            t_end = time.monotonic() + WAIT_S
            while True:
                try:
                    assert await b.call_method(f"{idx}:TakeControl") == "you have control"
                    break
                except BadUserAccessDenied:
                    if time.monotonic() > t_end:
                        raise
                    await asyncio.sleep(0.1)
            await b.call_method(f"{idx}:ReleaseControl")
    asyncio.run(go())


def test_the_encrypted_endpoint_with_the_certificate_made_on_first_start(live, tmp_path):
    cert = live.pki / "server_cert.der"
    assert cert.is_file() and (live.pki / "server_key.pem").stat().st_mode & 0o077 == 0
    key_c, cert_c = tmp_path / "client_key.pem", tmp_path / "client_cert.der"

    async def go():
        await setup_self_signed_certificate(
            key_c, cert_c, "urn:feeder_bt:test-client", "localhost",
            [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "test client"})
        c = client(live.url, ALICE)
        await c.set_security(SecurityPolicyBasic256Sha256, str(cert_c), str(key_c),
                             server_certificate=str(cert),
                             mode=ua.MessageSecurityMode.SignAndEncrypt)
        async with c:
            idx, node = await cell_node(c)
            assert await read(node, idx, "Scenario") == "lenses"
    asyncio.run(go())


def test_the_certificate_is_kept_across_starts(live, tmp_path):
    before = (live.pki / "server_cert.der").read_bytes()
    scenario, spec = load_scenario(LENSES)
    clock = SimClock()
    hal = make_sim_hal(scenario, spec, clock, 1)
    cell = Cell(spec, hal, clock)
    cell.load(scenario)
    again = CellUaServer(cell, PlantOptions(opcua="127.0.0.1:0", opcua_users=str(
        make_users(tmp_path / "u.json")), opcua_pki=str(live.pki)), LENSES)
    again.start()
    again.close()
    hal.close()
    assert (live.pki / "server_cert.der").read_bytes() == before


def test_option_mistakes_are_one_line(tmp_path):
    users = str(make_users(tmp_path / "users.json"))
    base = {"scenario": LENSES, "duration": 1.0, "view": "none", "db": None}
    with pytest.raises(FeederError, match="drop --fast"):
        run_job(RunOptions(**base, fast=True, plant=PlantOptions(opcua="127.0.0.1:0",
                                                                  opcua_users=users)))
    with pytest.raises(FeederError, match="each keep their own control token"):
        run_job(RunOptions(**base, ui="127.0.0.1:0", users=users,
                           plant=PlantOptions(opcua="127.0.0.1:0", opcua_users=users)))
    with pytest.raises(FeederError, match="loopback only"):
        run_job(RunOptions(**base, plant=PlantOptions(opcua="0.0.0.0:0", opcua_users=users,
                                                      opcua_insecure=True)))
    import socket
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(FeederError, match=f"--opcua 127.0.0.1:{port}: .*in use"):
            run_job(RunOptions(**base, plant=PlantOptions(
                opcua=f"127.0.0.1:{port}", opcua_users=users, part_server="127.0.0.1:0",
                opcua_pki=str(tmp_path / "pki"))))
    with pytest.raises(FeederError, match="no users"):
        run_job(RunOptions(**base, plant=PlantOptions(
            opcua="127.0.0.1:0", opcua_users=str(tmp_path / "nobody.json"))))


def test_a_user_removed_while_logged_in_can_no_longer_command(live):
    users = UsersFile(live.ua.users.path)

    async def go():
        async with client(live.url, BOB) as bob:
            idx, b = await cell_node(bob)
            assert await b.call_method(f"{idx}:TakeControl") == "you have control"
            users.remove("bob")
            try:
                with pytest.raises(BadUserAccessDenied):
                    await b.call_method(f"{idx}:Start")
                assert live.ua.control.holder is None      # and control went with him
            finally:
                users.add(*BOB)
    asyncio.run(go())


def test_guesses_from_elsewhere_do_not_keep_the_rightful_user_out(tmp_path):
    """The rule on the OPC UA surface: lock-outs count per address and per
    name-and-address, so a guesser elsewhere slows itself, not alice; every failure and
    lock-out is recorded."""
    from feeder_bt.plant.ua_security import PEER, UaUsers
    users = UsersFile(tmp_path / "users.json")
    users.add(*ALICE)
    heard: list[tuple[str, str, dict]] = []
    ua_users = UaUsers(users, lambda kind, user="-", **data: heard.append((kind, user, data)))

    def login(ip: str, password: str):
        token = PEER.set(ip)
        try:
            return ua_users.get_user(None, username=ALICE[0], password=password)
        finally:
            PEER.reset(token)

    for _ in range(12):
        assert login("10.9.8.7", "wrong guess") is None
    assert login("10.9.8.7", ALICE[1]) is None           # the guesser is locked out ...
    user = login("127.0.0.1", ALICE[1])                   # ... alice at her desk is not
    assert user is not None and user.name == ALICE[0]
    kinds = [k for k, _, _ in heard]
    assert kinds.count("login_failed") >= 3 and "login_locked" in kinds
    assert "login_refused" in kinds
    assert all(d["surface"] == "opcua" for _, _, d in heard)
    assert {d["ip"] for _, _, d in heard} == {"10.9.8.7"}


def test_a_refusal_keeps_its_reason(live):
    """asyncua's ``call_method`` raises on the bad status and drops the output arguments;
    ``plant.opcua_call.call`` keeps the refusal's one line."""
    from feeder_bt.plant.opcua_call import Refused, call

    async def go():
        async with client(live.url, BOB) as bob:
            idx, b = await cell_node(bob)
            with pytest.raises(BadUserAccessDenied) as plain:      # asyncua: no reason
                await b.call_method(f"{idx}:Start")
            assert "take control first" not in str(plain.value)
            with pytest.raises(Refused) as e:
                await call(b, f"{idx}:Start")
            assert "take control first" in str(e.value) and "BadUserAccessDenied" in str(e.value)
            assert isinstance(e.value, BadUserAccessDenied)       # old handlers still catch it
            assert await call(b, f"{idx}:TakeControl") == "you have control"
            assert await call(b, f"{idx}:ReleaseControl") == "control released"
    asyncio.run(go())


FLOOD = 40             # silent connections from the client's own address, reopened as closed
ROUNDS = 20            # before the lobby, 1 in 5 or so was reset: 20 catch it
GOT_IN_S = 5.0         # generous: the design, not the machine's speed, lets the client in


async def _log_in_and_read(url: str) -> tuple[str, float]:
    """Alice connects, logs in and reads the state: the state (or the error), and how
    long it took."""
    t0 = time.monotonic()
    try:
        async def go() -> str:
            async with client(url, ALICE) as c:
                idx, node = await cell_node(c)
                return await read(node, idx, "State")
        state = await asyncio.wait_for(go(), WAIT_S)
    except Exception as e:          # a reset before the Hello was read, a timeout
        state = f"{type(e).__name__}: {e}"
    return state, time.monotonic() - t0


def test_a_silent_flood_from_the_client_s_own_address_never_keeps_it_out(tmp_path):
    """40 connections from 127.0.0.1 that never send a byte, opened again as fast as the
    server closes them, and alice from 127.0.0.1 too: she connects, logs in and reads the
    state 20 times of 20, each within 5 s. Silent connections wait in the gate's lobby
    (``ConnLimits.lobby``, 256), outside the per-address cap, and only another silent one
    takes a place there: she could be closed before her Hello only by a lobby full of
    silent ones newer than hers, and the flood has 40. (Before the lobby the flood churned through the cap of 16 and
    she was reset before her Hello was read: 15, 18 and 18 of 20 got in.)"""
    from tests.support.floodutil import ReopeningFlood

    live = LiveCell(tmp_path)
    port = live.port
    flood = ReopeningFlood(port, FLOOD)
    try:
        end = time.monotonic() + WAIT_S
        while live.ua.gate.counts["admitted"] < FLOOD:     # the flood is in
            assert time.monotonic() < end, live.ua.gate.stats()
            time.sleep(0.05)
        rounds = [asyncio.run(_log_in_and_read(live.url)) for _ in range(ROUNDS)]
        got_in = sum(state == "STOPPED" for state, _ in rounds)
        assert got_in == ROUNDS, f"{got_in} of {ROUNDS} got in: {rounds}"
        assert max(took for _, took in rounds) < GOT_IN_S, rounds
        stats = live.ua.gate.stats()
        assert stats["open"] <= live.ua.gate.total + live.ua.gate.lobby, stats
        assert stats["admitted"] >= FLOOD + ROUNDS, stats
        # the flood is held, not churned: nobody was closed to make room, nobody refused
        assert stats.get("evicted", 0) == 0 and stats.get("refused", 0) == 0, stats
    finally:
        flood.close()
        live.close()
