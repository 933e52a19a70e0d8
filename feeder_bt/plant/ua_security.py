"""Who may talk to the cell's OPC UA server, and who is calling (plant/opcua.py).

- ``UaUsers``: user name and password against the users file of ``feeder users``, judged
  by the dashboard's ``LoginGuard`` (per address and per name-and-address, a name under
  attack slowed, never a lock-out of the rightful user's own address) and recorded like
  the dashboard's logins; anonymous and certificate-only identities are refused;
- the session hooks: asyncua hands a method callback only the object and the arguments,
  so the session making a call is put in a context variable around
  ``InternalSession.call`` (the callback runs in the same task), and
  ``InternalSession.close_session`` tells the server when a session ends, so that its
  control is released. Installed once per process, idempotent.
"""

from __future__ import annotations

import contextvars
import ipaddress
from pathlib import Path
from typing import Any

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_session import InternalSession
from asyncua.server.user_managers import UserManager

from feeder_bt.control.guard import Attempt, LoginGuard
from feeder_bt.control.users import UsersFile, default_path

SESSION: contextvars.ContextVar[InternalSession | None] = contextvars.ContextVar(
    "feeder_ua_session", default=None)
#: the client address of the session being activated (asyncua does not tell get_user)
PEER: contextvars.ContextVar[str] = contextvars.ContextVar("feeder_ua_peer", default="?")
CLOSED: dict[int, Any] = {}            # id(InternalServer) -> callback(session)


def install_session_hooks() -> None:
    if getattr(InternalSession, "_feeder_hooks", False):
        return
    call, close = InternalSession.call, InternalSession.close_session
    activate = InternalSession.activate_session

    def activate_with_peer(self, params, peer_certificate):
        peer = self.name if isinstance(self.name, tuple) else (str(self.name),)
        token = PEER.set(str(peer[0]))
        try:
            return activate(self, params, peer_certificate)
        except ServiceError as e:       # refused before our user manager is asked
            users = getattr(self.iserver, "user_manager", None)
            if e.code == ua.StatusCodes.BadIdentityTokenRejected and \
                    isinstance(users, UaUsers):
                users.record("login_refused", "-", ip=str(peer[0])[:64], surface="opcua",
                             locked_by="anonymous")
            raise
        finally:
            PEER.reset(token)

    async def call_with_session(self, params):
        token = SESSION.set(self)
        try:
            return await call(self, params)
        finally:
            SESSION.reset(token)

    async def close_and_tell(self, delete_subs: bool = True) -> None:
        await close(self, delete_subs)
        fn = CLOSED.get(id(self.iserver))
        if fn is not None:
            fn(self)

    InternalSession.call = call_with_session
    InternalSession.close_session = close_and_tell
    InternalSession.activate_session = activate_with_peer
    InternalSession._feeder_hooks = True


class UaUsers(UserManager):
    """User name and password against the users file, judged by the dashboard's rules:
    guesses from elsewhere never lock the rightful user's own address out. ``record(kind,
    user, **data)`` receives the same access events as the dashboard's (failed logins,
    lock-outs, refusals)."""

    def __init__(self, users: UsersFile, record: Any = None) -> None:
        self.users = users
        self.record = record or (lambda kind, user="-", **data: None)
        self.guard = LoginGuard(self._secret_of)

    def _secret_of(self, name: str) -> str | None:
        entry = self.users.load_or_empty().get(name)
        return None if entry is None else str(entry.get("hash", ""))

    def get_user(self, iserver, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        if not username or password is None:
            self.record("login_refused", "-", ip=PEER.get(), surface="opcua",
                        locked_by="anonymous")
            return None                    # anonymous, or a certificate alone: refused
        attempt = Attempt(username[:64], PEER.get())
        shown = username if self.users.exists(username) else "(unknown name)"
        verdict = self.guard.check(attempt)
        if verdict.wait_s > 0 or not self.guard.begin(attempt, False):
            self.record("login_refused", shown, ip=attempt.ip, surface="opcua",
                        locked_by=verdict.why or "busy", wait_s=round(verdict.wait_s, 1))
            return None
        try:
            ok = self.users.verify(username, password)
        finally:
            self.guard.end(attempt, False)
        if not ok:
            locks = self.guard.failure(attempt, False)
            self.record("login_failed", shown, ip=attempt.ip, surface="opcua")
            for why, secs in locks:
                self.record("login_locked", shown, ip=attempt.ip, surface="opcua", by=why,
                            seconds=round(secs, 1))
            return None
        self.guard.success(attempt, False)
        return User(role=UserRole.User, name=username)


def default_pki() -> Path:
    """Beside the users file: ``$XDG_CONFIG_HOME/feeder_bt/opcua``."""
    return default_path().parent / "opcua"


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


# ---------------------------------------------------------------------------- connections
#: id(InternalServer) -> its ConnGate; consulted by the patched protocol factory
GATES: dict[int, Any] = {}
ACTIVATION_S = 10.0        # a connection with no activated session this long is closed


class _GatedUa:
    """asyncua's per-connection protocol behind a ``ConnGate``: over the cap it is never
    made (no UaProcessor, no task, no log line); when full, the oldest connection without
    an activated session makes room. Everything else is passed through."""

    def __init__(self, inner: Any, gate: Any) -> None:
        self.inner, self.gate, self.transport = inner, gate, None

    def _busy(self) -> bool:
        proc = self.inner.processor
        session = getattr(proc, "session", None)
        return session is not None and session.is_activated()

    def connection_made(self, transport: Any) -> None:
        if not self.gate.admit(transport, self._busy):
            return
        self.transport = transport
        self.inner.connection_made(transport)

    def connection_lost(self, exc: BaseException | None) -> None:
        if self.transport is None:
            return
        self.gate.release(self.transport)
        self.inner.connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        if self.transport is not None and self.gate.heard(self.transport):
            self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return None

    def pause_writing(self) -> None:
        pass

    def resume_writing(self) -> None:
        pass


def install_gate_hook() -> None:
    """Make asyncua's ``BinaryServer`` build each connection's protocol behind the gate of
    its server (if one is registered in ``GATES``). Once per process, idempotent."""
    from asyncua.server.binary_server_asyncio import BinaryServer
    if getattr(BinaryServer, "_feeder_gate", False):
        return
    make = BinaryServer._make_protocol

    def gated(self):
        proto = make(self)
        gate = GATES.get(id(self.iserver))
        return proto if gate is None else _GatedUa(proto, gate)

    BinaryServer._make_protocol = gated
    BinaryServer._feeder_gate = True
