"""Who may talk to the cell's OPC UA server, and who is calling (plant/opcua.py).

- ``UaUsers``: user name and password against the users file of ``feeder users``, with the
  dashboard's failed-login limiter; anonymous and certificate-only identities are refused;
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

from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.internal_session import InternalSession
from asyncua.server.user_managers import UserManager

from ..ui.control import LoginLimiter
from ..ui.users import UsersFile, default_path

SESSION: contextvars.ContextVar[InternalSession | None] = contextvars.ContextVar(
    "feeder_ua_session", default=None)
CLOSED: dict[int, Any] = {}            # id(InternalServer) -> callback(session)


def install_session_hooks() -> None:
    if getattr(InternalSession, "_feeder_hooks", False):
        return
    call, close = InternalSession.call, InternalSession.close_session

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
    InternalSession._feeder_hooks = True


class UaUsers(UserManager):
    """User name and password against the users file; failures slow the next try down."""

    def __init__(self, users: UsersFile) -> None:
        self.users = users
        self.limiter = LoginLimiter()

    def get_user(self, iserver, username: str | None = None, password: str | None = None,
                 certificate: Any = None) -> User | None:
        if not username or password is None:
            return None                    # anonymous, or a certificate alone: refused
        keys = (f"user:{username}",)
        if self.limiter.locked_for(keys) > 0 or not self.limiter.begin(keys):
            return None
        try:
            ok = self.users.verify(username, password)
        finally:
            self.limiter.end(keys)
        if not ok:
            self.limiter.failure(keys)
            return None
        self.limiter.success(keys)
        return User(role=UserRole.User, name=username)


def default_pki() -> Path:
    """Beside the users file: ``$XDG_CONFIG_HOME/feeder_bt/opcua``."""
    return default_path().parent / "opcua"


def is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"
