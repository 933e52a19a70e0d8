"""``feeder run --opcua [HOST:]PORT``: the cell as an OPC UA server (docs/plant.md).

A thin translation onto what the dashboard already uses: the same command path
(``ui.bridge.Bridge`` in front of ``ui.operate.CellOps``: commands queued to the tick
thread, checked there, refused with the reason), the same status (``ui.status.CellPanel``
snapshots), the same users file (``feeder users``, scrypt hashes), the same rules of
control (``ui.control.Control``: one session at a time holds control; only it may start,
stop or set speeds) and the same failed-login limiter.

asyncua runs on its own thread and event loop. The tick thread calls ``pump()`` after
each tick: queued commands run, a snapshot is published now and then, and the UA loop is
woken to copy it into the address space and to fire an event for each new state change
or fault in the message window.

Secure by default: the only endpoint is Basic256Sha256 sign-and-encrypt with a
certificate made on first start (kept in ``--opcua-pki``), anonymous access is off, and a
user name and password from the users file are required. ``--opcua-insecure`` adds an
unsecured endpoint, on a loopback address only, for tests.
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
from concurrent.futures import Future
from pathlib import Path
from typing import Any

from asyncua import Server, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.server.internal_session import InternalSession
from cryptography.x509.oid import ExtendedKeyUsageOID

from feeder_bt.control.access import AccessRecorder
from feeder_bt.control.bridge import Bridge, Outcome
from feeder_bt.control.cell import Cell
from feeder_bt.control.conns import ConnGate, ConnLimits
from feeder_bt.control.operate import SPEED_KEYS, CellOps
from feeder_bt.control.sessions import Control, Session
from feeder_bt.control.status import CellPanel
from feeder_bt.control.users import UsersFile
from feeder_bt.core.addresses import parse_hostport
from feeder_bt.core.errors import FeederError
from feeder_bt.plant.options import PlantOptions
from feeder_bt.plant.ua_security import (
    ACTIVATION_S,
    CLOSED,
    GATES,
    SESSION,
    UaUsers,
    default_pki,
    install_gate_hook,
    install_session_hooks,
    is_loopback,
)

NAMESPACE = "urn:feeder_bt"
DEFAULT_PORT = 4840
#: connections that have not sent a byte, held outside the caps (``ConnLimits.lobby``):
#: more than one asyncio accept burst (asyncua listens with asyncio's backlog, 100), so a
#: burst of silent ones cannot close a client between its accept and its Hello. With the
#: caps (128 that spoke), at most 384 connections open: 384 descriptors.
LOBBY = 256
COMMAND_TIMEOUT_S = 10.0
SEVERITY = {"fault": 800, "state": 300, "recovered": 400, "operator": 200}
EVENT_KINDS = frozenset(SEVERITY)

# status key -> (browse name, variant type)
VARIABLES: dict[str, tuple[str, ua.VariantType]] = {
    "state": ("State", ua.VariantType.String),
    "scenario": ("Scenario", ua.VariantType.String),
    "fault": ("Fault", ua.VariantType.String),
    "ppm": ("PartsPerMin", ua.VariantType.Double),
    "ppm_window": ("PartsPerMinLastMinute", ua.VariantType.Double),
    "total_fed": ("Retrieved", ua.VariantType.Int64),
    "queue": ("QueueLength", ua.VariantType.Int64),
    "auto_adjust": ("AutoAdjust", ua.VariantType.Boolean),
    "control": ("ControlHolder", ua.VariantType.String),
}
COUNTERS = {"located": "Located", "missed": "Missed", "too_far": "TooFar",
            "unreachable": "Unreachable", "dropped": "Dropped", "unreported": "Unreported"}
SPEEDS = {"horizontal_mm_s": "HorizontalMmS", "incline_pct": "InclinePct",
          "robot_speed_pct": "RobotSpeedPct"}


class CellUaServer:
    """One cell's OPC UA server; ``start()`` returns the endpoint URL."""

    def __init__(self, cell: Cell, opts: PlantOptions, scenario_path: str | None = None,
                 cell_path: str | None = None) -> None:
        self.cell, self.opts = cell, opts
        self.host, self.port = parse_hostport(opts.opcua or "", DEFAULT_PORT, "--opcua")
        if opts.opcua_insecure and not is_loopback(self.host):
            raise FeederError(f"--opcua-insecure: an unsecured endpoint is for loopback only "
                              f"(127.0.0.1), not {self.host}")
        self.users = UsersFile(opts.opcua_users)
        self.pki = Path(opts.opcua_pki).expanduser() if opts.opcua_pki else default_pki()
        scenario_path = scenario_path or (cell.scenario.path if cell.scenario else ".")
        cell_file = cell_path or (cell.scenario.cell_path if cell.scenario else "")
        self.ops = CellOps(cell, Path(scenario_path).resolve().parent, Path(cell_file))
        self.panel = CellPanel(cell, self.ops.limits, lambda: sorted(self.ops.scenarios))
        self.bridge = Bridge(self.ops.execute, self._snapshot, hz=2.0)
        self.control = Control()
        self.sessions: dict[int, Session] = {}          # id(InternalSession) -> Session
        self.url = f"opc.tcp://{self.host}:{self.port}/feeder"
        self.loop: asyncio.AbstractEventLoop | None = None
        self.thread: threading.Thread | None = None
        self.server: Server | None = None
        self.ready: Future = Future()
        self.stopping: asyncio.Event | None = None
        self.dirty: asyncio.Event | None = None
        self.nodes: dict[str, Any] = {}
        self.by_type: dict[str, Any] = {}
        self.faults: dict[str, Any] = {}
        self.last_msg = 0
        self.events_sent = 0
        self.refused = 0
        self.gate = ConnGate("OPC UA", ConnLimits(total=128, per_address=16, lobby=LOBBY,
                                                  header_s=ACTIVATION_S))

    # ------------------------------------------------------------------ tick thread
    def _snapshot(self):
        status, history, messages = self.panel.snapshot()
        s = self.cell.stats
        status["unreachable"] = s.counts["unreachable"]
        status["dropped"] = s.counts["dropped"]
        status["unreported"] = s.counts["unreported"]
        status["faults"] = dict(s.faults)
        return status, history, messages

    def pump(self) -> None:
        self.bridge.pump()

    def closing(self) -> None:
        self.bridge.close()

    # ------------------------------------------------------------------ life
    def start(self) -> str:
        """Serve on a thread of its own; returns once the endpoint listens."""
        logging.getLogger("asyncua").setLevel(logging.CRITICAL)   # one-line errors
        install_session_hooks()
        install_gate_hook()
        self.bridge.publish()
        self.thread = threading.Thread(target=self._main, name="opcua", daemon=True)
        self.thread.start()
        try:
            self.ready.result(timeout=60.0)
        except OSError as e:
            raise FeederError(f"--opcua {self.opts.opcua}: {e.strerror or e}") from None
        return self.url

    def _main(self) -> None:
        try:
            asyncio.run(self._serve())
        except BaseException as e:     # reported to start(), never a thread traceback
            if not self.ready.done():
                self.ready.set_exception(e)

    async def _serve(self) -> None:
        self.loop = asyncio.get_running_loop()
        self.stopping, self.dirty = asyncio.Event(), asyncio.Event()
        # failed logins, lock-outs and refusals go to the event log as the dashboard's do
        record = AccessRecorder(
            lambda kind, user, data: self.bridge.submit("access", {"kind": kind, **data}, user))
        server = self.server = Server(user_manager=UaUsers(self.users, record))
        await server.init()
        CLOSED[id(server.iserver)] = self._session_closed
        # connections: our gate caps them per address and in all, and makes room
        # for a newcomer by closing the oldest without an activated session. asyncua's own
        # max_connections is only a backstop far above ours: it counts a closed connection
        # until its connection_lost runs, so under a burst it would refuse (reset) the very
        # client our gate let in. Its watchdog closes a connection that has not activated a
        # session within ACTIVATION_S (in the lobby too: a silent one lives 10 s at most).
        GATES[id(server.iserver)] = self.gate
        server.iserver.max_connections = (self.gate.total + self.gate.lobby) * 8 + 1000
        server.iserver.max_pending_activation_seconds = ACTIVATION_S
        self.gate.loop_errors(self.loop)      # asyncua's own log is silenced (start())
        server.set_endpoint(self.url)
        server.set_server_name(f"feeder_bt cell {self.cell.cell.name}")
        await server.set_application_uri(f"{NAMESPACE}:cell:{self.cell.cell.name}")
        policies = [ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt]
        if self.opts.opcua_insecure:
            policies.append(ua.SecurityPolicyType.NoSecurity)
        server.set_security_policy(policies)
        server.set_identity_tokens([ua.UserNameIdentityToken])
        await self._certificate(server)
        await self._address_space(server)
        self.bridge.subscribe(self._published)
        await server.start()
        try:
            sock = server.bserver._server.sockets[0]          # port 0: the one given
            self.port = int(sock.getsockname()[1])
            self.url = f"opc.tcp://{self.host}:{self.port}/feeder"
        except (AttributeError, IndexError):
            pass
        self.ready.set_result(self.url)
        publisher = asyncio.create_task(self._publisher())
        await self.stopping.wait()
        publisher.cancel()
        self.bridge.unsubscribe(self._published)
        await server.stop()
        CLOSED.pop(id(server.iserver), None)
        GATES.pop(id(server.iserver), None)
        self.gate.tell()

    async def _certificate(self, server: Server) -> None:
        """The server's key and self-signed certificate, made on first start."""
        self.pki.mkdir(parents=True, exist_ok=True, mode=0o700)
        key, cert = self.pki / "server_key.pem", self.pki / "server_cert.der"
        await setup_self_signed_certificate(
            key, cert, f"{NAMESPACE}:cell:{self.cell.cell.name}", socket.gethostname(),
            [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
            {"commonName": f"feeder_bt {self.cell.cell.name}", "organizationName": "feeder_bt"})
        key.chmod(0o600)
        await server.load_certificate(str(cert))
        await server.load_private_key(str(key))

    async def _address_space(self, server: Server) -> None:
        idx = await server.register_namespace(NAMESPACE)
        self.idx = idx
        cell = self.cell_node = await server.nodes.objects.add_object(idx, "Cell")
        status = self.bridge.latest().status
        for key, (name, vt) in VARIABLES.items():
            self.nodes[key] = (await cell.add_variable(idx, name, _value(status.get(key), vt),
                                                        varianttype=vt), vt)
        speeds = await cell.add_object(idx, "Speeds")
        for key, name in SPEEDS.items():
            vt = ua.VariantType.Double
            self.nodes[f"speeds.{key}"] = (await speeds.add_variable(idx, name, 0.0,
                                                                     varianttype=vt), vt)
        counters = await cell.add_object(idx, "Counters")
        for key, name in COUNTERS.items():
            vt = ua.VariantType.Int64
            self.nodes[key] = (await counters.add_variable(idx, name, 0, varianttype=vt), vt)
        self.by_type_node = await cell.add_object(idx, "RetrievedByType")
        self.faults_node = await cell.add_object(idx, "Faults")
        for name in ("Start", "Stop", "Pause", "Resume", "Reset"):
            await cell.add_method(idx, name, self._command(name.lower()), [],
                                  [ua.VariantType.String])
        await cell.add_method(idx, "SetSpeeds", self._set_speeds,
                              [_arg(n, "NaN: leave as it is") for n in SPEEDS.values()],
                              [ua.VariantType.String])
        await cell.add_method(idx, "TakeControl", self._take, [], [ua.VariantType.String])
        await cell.add_method(idx, "ReleaseControl", self._release, [],
                              [ua.VariantType.String])
        self.etype = await server.create_custom_event_type(
            idx, "CellEventType", ua.ObjectIds.BaseEventType,
            [("Kind", ua.VariantType.String), ("OldState", ua.VariantType.String),
             ("NewState", ua.VariantType.String)])
        self.events = await server.get_event_generator(self.etype, cell)
        self.alarm = await server.get_event_generator(ua.ObjectIds.OffNormalAlarmType, cell)
        self.alarm_active = False
        self.last_msg = max((m.seq for m in self.bridge.latest().messages), default=0)

    def close(self) -> None:
        if self.loop is not None and self.stopping is not None and not self.loop.is_closed():
            try:
                self.loop.call_soon_threadsafe(self.stopping.set)
            except RuntimeError:             # the loop ended meanwhile
                pass
        if self.thread is not None:
            self.thread.join(timeout=10.0)

    def report(self) -> dict[str, Any]:
        return {"url": self.url, "events": self.events_sent, "refused": self.refused,
                "connection_limits": self.gate.stats(),
                **self.ops.report()}

    # ------------------------------------------------------------------ publishing
    def _published(self) -> None:
        """Tick thread, after a snapshot: wake the UA loop (never blocks)."""
        if self.loop is not None and self.dirty is not None:
            self.loop.call_soon_threadsafe(self.dirty.set)

    async def _publisher(self) -> None:
        assert self.dirty is not None
        while True:
            await self.dirty.wait()
            self.dirty.clear()
            try:
                await self._copy()
            except Exception as e:          # the address space goes stale; the cell feeds on
                logging.getLogger(__name__).warning("OPC UA update failed: %s", e)

    async def _copy(self) -> None:
        pub = self.bridge.latest()
        if pub is None:
            return
        status = pub.status
        holder = self.control.holder
        status["control"] = holder.user if holder is not None else ""
        for key, (node, vt) in self.nodes.items():
            if key.startswith("speeds."):
                v = (status.get("speeds") or {}).get(key[7:])
            else:
                v = status.get(key)
            await node.write_value(ua.Variant(_value(v, vt), vt))
        await self._per_name(self.by_type, self.by_type_node, status.get("fed_by_type") or {})
        await self._per_name(self.faults, self.faults_node, status.get("faults") or {})
        await self._fault_alarm(status)
        for msg in pub.messages:
            if msg.seq <= self.last_msg:
                continue
            self.last_msg = msg.seq
            if msg.kind in EVENT_KINDS:
                await self._event(msg)

    async def _per_name(self, known: dict[str, Any], parent, values: dict[str, int]) -> None:
        for name, v in values.items():
            if name not in known:
                known[name] = await parent.add_variable(self.idx, name, 0,
                                                        varianttype=ua.VariantType.Int64)
            await known[name].write_value(ua.Variant(int(v), ua.VariantType.Int64))

    async def _fault_alarm(self, status: dict[str, Any]) -> None:
        """The cell's fault as an OffNormalAlarm condition: active from the fault until the
        reset. (Acknowledging it from a client is not implemented: Reset clears it.)"""
        active = status.get("state") in ("FAULTING", "FAULT")
        if active == self.alarm_active:
            return
        self.alarm_active = active
        ev = self.alarm.event
        text = (status.get("fault") or "cell fault") if active else "fault reset"
        ev.Message = ua.LocalizedText(text)
        ev.Severity = 900 if active else 100
        ev.SourceName = "Cell"
        ev.ConditionName = "CellFault"
        ev.Retain = active
        ev.EnabledState = ua.LocalizedText("Enabled")
        setattr(ev, "EnabledState/Id", True)
        ev.ActiveState = ua.LocalizedText("Active" if active else "Inactive")
        setattr(ev, "ActiveState/Id", active)
        ev.AckedState = ua.LocalizedText("Unacknowledged" if active else "Acknowledged")
        setattr(ev, "AckedState/Id", not active)
        await self.alarm.trigger()
        self.events_sent += 1

    async def _event(self, msg) -> None:
        ev = self.events.event
        ev.Message = ua.LocalizedText(msg.text)
        ev.Severity = SEVERITY.get(msg.kind, 100)
        ev.Kind = msg.kind
        old, new = "", ""
        if msg.kind == "state" and "\u2192" in msg.text:
            old, new = (p.strip() for p in msg.text[len("state "):].split("\u2192", 1))
        ev.OldState, ev.NewState = old, new
        await self.events.trigger()
        self.events_sent += 1

    # ------------------------------------------------------------------ sessions, control
    def _session(self) -> Session | None:
        ua_session = SESSION.get()
        if ua_session is None or ua_session.user is None or not ua_session.user.name:
            return None
        s = self.sessions.get(id(ua_session))
        if not self.users.exists(ua_session.user.name):     # removed since the login
            if s is not None:
                self.control.drop(s.token)
            return None
        if s is None:
            s = self.sessions[id(ua_session)] = Session(
                token=str(ua_session.session_id), user=ua_session.user.name, ip="",
                created=0.0, seen=0.0)
        return s

    def _session_closed(self, ua_session: InternalSession) -> None:
        s = self.sessions.pop(id(ua_session), None)
        if s is not None and self.control.drop(s.token):
            self.bridge.submit("note", {"action": "control dropped (OPC UA session closed)"},
                               s.user)
            self._dirty()

    def _dirty(self) -> None:
        if self.dirty is not None:
            self.dirty.set()

    async def _take(self, parent) -> list[ua.Variant] | ua.CallMethodResult:
        s = self._session()
        if s is None:
            return self._refuse(ua.StatusCodes.BadUserAccessDenied, "log in first")
        ok, text = self.control.take(s)
        if not ok:
            return self._refuse(ua.StatusCodes.BadUserAccessDenied, text)
        self.bridge.submit("note", {"action": "take control (OPC UA)"}, s.user)
        self._dirty()
        return [ua.Variant(text, ua.VariantType.String)]

    async def _release(self, parent) -> list[ua.Variant] | ua.CallMethodResult:
        s = self._session()
        if s is None:
            return self._refuse(ua.StatusCodes.BadUserAccessDenied, "log in first")
        ok, text = self.control.release(s)
        if not ok:
            return self._refuse(ua.StatusCodes.BadUserAccessDenied, text)
        self.bridge.submit("note", {"action": "release control (OPC UA)"}, s.user)
        self._dirty()
        return [ua.Variant(text, ua.VariantType.String)]

    def _command(self, name: str):
        async def method(parent) -> list[ua.Variant] | ua.CallMethodResult:
            return await self._run(name, {})
        return method

    async def _set_speeds(self, parent, *args: ua.Variant):
        values = [a.Value if isinstance(a, ua.Variant) else a for a in args]
        if len(values) != len(SPEED_KEYS):
            return self._refuse(ua.StatusCodes.BadArgumentsMissing,
                                f"SetSpeeds takes {len(SPEED_KEYS)} numbers")
        speeds: dict[str, float] = {}
        for key, v in zip(SPEED_KEYS, values, strict=True):
            # a Double (or any number but a Boolean); anything else is the caller's mistake,
            # never our BadUnexpectedError
            if v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int | float):
                return self._refuse(ua.StatusCodes.BadInvalidArgument,
                                    f"SetSpeeds: {SPEEDS[key]} must be a Double, got "
                                    f"{type(v).__name__}")
            try:
                f = float(v)
            except OverflowError:
                return self._refuse(ua.StatusCodes.BadInvalidArgument,
                                    f"SetSpeeds: {SPEEDS[key]} is out of range")
            if f == f:                               # NaN: leave as it is
                speeds[key] = f
        return await self._run("speeds", speeds)

    async def _run(self, name: str, args: dict[str, Any]):
        s = self._session()
        if s is None:
            return self._refuse(ua.StatusCodes.BadUserAccessDenied, "log in first")
        if not self.control.is_holder(s):
            return self._refuse(ua.StatusCodes.BadUserAccessDenied, self.control.refusal(s))
        fut = self.bridge.submit(name, args, s.user)
        try:
            outcome: Outcome = await asyncio.wait_for(asyncio.wrap_future(fut),
                                                      COMMAND_TIMEOUT_S)
        except TimeoutError:
            fut.cancel()
            return self._refuse(ua.StatusCodes.BadTimeout, "the cell did not answer in time")
        if not outcome.ok:
            code = {400: ua.StatusCodes.BadInvalidArgument,
                    503: ua.StatusCodes.BadResourceUnavailable}.get(
                        outcome.status, ua.StatusCodes.BadInvalidState)
            return self._refuse(code, outcome.message)
        self._dirty()
        return [ua.Variant(outcome.message, ua.VariantType.String)]

    def _refuse(self, code: int, text: str) -> ua.CallMethodResult:
        self.refused += 1
        res = ua.CallMethodResult()
        res.StatusCode = ua.StatusCode(code)
        res.OutputArguments = [ua.Variant(text, ua.VariantType.String)]
        return res


def _arg(name: str, text: str) -> ua.Argument:
    a = ua.Argument()
    a.Name = name
    a.DataType = ua.NodeId(ua.ObjectIds.Double)
    a.ValueRank = -1
    a.Description = ua.LocalizedText(text)
    return a


def _value(v: Any, vt: ua.VariantType) -> Any:
    if vt is ua.VariantType.String:
        return "" if v is None else str(v)
    if vt is ua.VariantType.Double:
        return 0.0 if v is None else float(v)
    if vt is ua.VariantType.Boolean:
        return bool(v)
    return 0 if v is None else int(v)
