"""``feeder replay --ui`` signs in with the dashboard's users file: the
blackboard and every node of a past run are the cell's business, and the Host check stops
only browsers, not scripts.

The same pieces as the dashboard: ``users.UsersFile`` (scrypt hashes, checked off the
loop), ``guard.LoginGuard`` (slowed per address and browser, never a lock-out of the
rightful user), ``control.Sessions`` (an HTTP-only, ``SameSite=Strict`` cookie, an idle
time and a lifetime from the users file's settings). Read-only: no control, no commands.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection, Request
from starlette.responses import Response
from starlette.routing import Route

from feeder_bt.control.access import Settings
from feeder_bt.control.guard import KNOWN_COOKIE, Attempt, LoginGuard, set_login_cookies
from feeder_bt.control.sessions import Session, Sessions, retry_after
from feeder_bt.control.users import (
    MAX_PASSWORD,
    NAME_RE,
    UsersError,
    UsersFile,
    _dummy_hash,
    verify_password,
)
from feeder_bt.ui.responses import client_ip, json_body, json_response, refuse, same_origin

COOKIE = "feeder_replay_session"
MAX_BODY = 16 * 1024
MAX_CHECKS = 2                 # password checks at once (a replay has a few viewers)


class ReplayLogin:
    """Sessions of the replay UI; ``routes`` are its login, logout and me."""

    def __init__(self, users: UsersFile, say: Callable[[str], None] | None = None) -> None:
        self.users = users
        try:
            st = Settings.of(users.section("settings"))
        except UsersError:
            st = Settings()
        self.sessions = Sessions(st.session_idle_s, lifetime_s=st.session_lifetime_s)
        self.guard = LoginGuard(users.secret_of)
        self.say = say or (lambda line: print(line, file=sys.stderr))
        self._checking = 0
        _dummy_hash()
        self.routes = [Route("/api/login", self.login, methods=["POST"]),
                       Route("/api/logout", self.logout, methods=["POST"]),
                       Route("/api/me", self.me)]

    def session(self, conn: HTTPConnection) -> Session | None:
        """The caller's live session, still bound to the user's password, or None."""
        s = self.sessions.get(conn.cookies.get(COOKIE))
        if s is not None and self.users.secret_of(s.user) != s.secret:
            self.sessions.end(s.token)          # removed, or a new password
            return None
        return s

    def may_read(self, request: Request) -> Response | None:
        return None if self.session(request) is not None else refuse("not logged in", 401)

    async def _body(self, request: Request) -> dict | Response:
        return await json_body(request, MAX_BODY)

    async def login(self, request: Request) -> Response:
        body = await self._body(request)
        if isinstance(body, Response):
            return body
        name, password = body.get("user"), body.get("password")
        if not isinstance(name, str) or not isinstance(password, str) or not name:
            return refuse("give a user name and a password", 400)
        real = NAME_RE.fullmatch(name) is not None
        attempt = Attempt(name[:64], client_ip(request),
                          request.cookies.get(KNOWN_COOKIE + name) if real else None)
        verdict = self.guard.check(attempt)
        if verdict.wait_s > 0:
            secs = retry_after(verdict.wait_s)
            return refuse(f"too many failed logins: try again in {secs} s", 429,
                          {"retry-after": str(secs)})
        favoured = verdict.trusted or self.guard.known(attempt)
        if self._checking >= MAX_CHECKS + (1 if favoured else 0) \
                or not self.guard.begin(attempt, verdict.trusted):
            return refuse("busy checking other logins: try again", 429, {"retry-after": "1"})
        self._checking += 1
        try:
            entry = self.users.load_or_empty().get(name) if real else None
            stored = str(entry["hash"]) if entry else _dummy_hash()
            good = await run_in_threadpool(verify_password, password[:MAX_PASSWORD + 1],
                                           stored) and entry is not None
        finally:
            self._checking -= 1
            self.guard.end(attempt, verdict.trusted)
        if not good:
            for why, secs in self.guard.failure(attempt, verdict.trusted):
                self.say(f"feeder replay: login locked ({why}, {secs:.0f} s) from "
                         f"{attempt.ip}")
            return refuse("wrong user name or password", 401)
        assert entry is not None
        self.guard.success(attempt, verdict.trusted)
        s = self.sessions.create(name, attempt.ip, str(entry["hash"]))
        resp = json_response({"ok": True, "user": name})
        set_login_cookies(resp, request, COOKIE, s.token, name, self.guard.issue(name))
        return resp

    async def logout(self, request: Request) -> Response:
        if not same_origin(request):
            return refuse("refused: request from another site", 403)
        self.sessions.end(request.cookies.get(COOKIE))
        resp = json_response({"ok": True})
        resp.delete_cookie(COOKIE, path="/", httponly=True, samesite="strict")
        return resp

    async def me(self, request: Request) -> Response:
        s = self.session(request)
        if s is None:
            return refuse("not logged in", 401)
        return json_response({"ok": True, "user": s.user})
