"""The operator UI's web app (Starlette); ``listener.UiServer`` runs it in a background thread.

Threading: the app runs on its own asyncio loop in the ``feeder-ui`` thread and never
touches the cell. It reads the bridge's latest published snapshot and submits commands
to the bridge; the tick thread wakes it with ``loop.call_soon_threadsafe`` after each
publish. Each websocket client has a sender task that always sends the *latest* snapshot
(updates published while it was busy are coalesced), and a client that cannot take one
within ``SEND_TIMEOUT_S`` is dropped; the cell never waits on any of this.

Security (docs/operator-ui.md): a request with a Host that is not ours is
refused before anything else (``access.Gate``); passwords are checked against the users
file's scrypt hashes off the loop, and failed logins are slowed per address and browser
(``guard``) without locking the rightful user out; a session lives in an HTTP-only,
``SameSite=Strict`` cookie, ends after an idle time and an absolute lifetime, and is bound to
the password it was opened with; control is freed when its holder has left; state-changing
requests must be JSON from the page's own origin (scheme included), parsed defensively; every
refusal is recorded (``access.AccessRecorder``); the page has a strict CSP.
"""

from __future__ import annotations

import asyncio
import json
import secrets
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.requests import HTTPConnection, Request
from starlette.responses import FileResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from feeder_bt.control.access import MAX_HOST_CHARS, AccessRecorder, Gate, Settings, allowed_hosts
from feeder_bt.control.bridge import Bridge, Outcome
from feeder_bt.control.guard import KNOWN_COOKIE, Attempt, LoginGuard, set_login_cookies
from feeder_bt.control.operate import COMMANDS
from feeder_bt.control.sessions import Control, Session, Sessions, retry_after
from feeder_bt.control.users import (
    MAX_PASSWORD,
    NAME_RE,
    UsersError,
    UsersFile,
    _dummy_hash,
    verify_password,
)
from feeder_bt.ui.camera import CameraFeed, CameraView
from feeder_bt.ui.openapi import spec as openapi_spec
from feeder_bt.ui.responses import (
    SecurityHeaders,
    client_ip,
    json_body,
    json_response,
    refuse,
    same_origin,
)
from feeder_bt.ui.treedata import tree_routes

COOKIE = "feeder_session"
COMMAND_TIMEOUT_S = 5.0       # the tick thread answers within a tick or two; else 503
SEND_TIMEOUT_S = 5.0          # a websocket client slower than this is dropped
MAX_BODY = 64 * 1024          # bytes: every request the page makes is a few hundred
MAX_CHECKS = 4                # password checks at once (16 MiB and ~50 ms of a core each)
STRANGER_CHECKS = 2           # ... of which strangers may hold at most this many: a known
                              # browser or address always finds a free one
STATIC = Path(__file__).parent / "static"

class _Client:
    """One open websocket: what it has been sent so far."""

    def __init__(self, ws: WebSocket, token: str) -> None:
        self.ws, self.token = ws, token
        self.wake = asyncio.Event()
        self.hist_t = -1.0
        self.msg_seq = 0
        self.pub_seq = -1                # the snapshot and session view last sent
        self.session = ""


class UiApp:
    """The web side's state (sessions, control, login guard, websocket clients) and routes.

    ``host`` is the bound address (for the Host allow-list); ``settings`` default to the
    users file's; ``clock`` drives sessions, control and the guard unless they are given.
    """

    def __init__(self, bridge: Bridge, users: UsersFile, *, sessions: Sessions | None = None,
                 control: Control | None = None, guard: LoginGuard | None = None,
                 settings: Settings | None = None, host: str = "127.0.0.1",
                 clock: Callable[[], float] = time.monotonic,
                 record: AccessRecorder | None = None,
                 camera: CameraFeed | None = None) -> None:
        self.bridge, self.users, self.host = bridge, users, host
        self.settings = settings if settings is not None else \
            Settings.of(users.section("settings"))
        st = self.settings
        # `is not None`, not `or`: an empty Sessions is falsy (it has a length)
        self.sessions = sessions if sessions is not None else \
            Sessions(st.session_idle_s, clock, st.session_lifetime_s)
        self.control = control if control is not None else Control(st.control_grace_s, clock)
        self.guard = guard if guard is not None else LoginGuard(users.secret_of, clock=clock)
        self.record = record if record is not None else AccessRecorder(
            lambda kind, user, data: bridge.submit("access", {"kind": kind, **data}, user),
            clock=clock)
        self.fixed_settings = settings is not None
        self.clients: set[_Client] = set()
        self._checking = 0               # password checks in flight
        self._strangers = 0              # ... of them by strangers
        self._stamp = users.stamp
        self._release_seq = users.section("release_control").get("seq")
        self._allowed = allowed_hosts(host, st.hosts)
        _dummy_hash()                    # computed now, not on the loop at the first login
        self.trace_view: Callable[[], Any] = lambda: None   # the trees' history (app.py)
        self.camera = CameraView(camera, self.watcher, lambda: self.settings.camera_fps, clock)
        self.app = Starlette(routes=[
            *tree_routes(lambda: self.trace_view(), self._may_watch, live=True),
            Route("/", self.index),
            Route("/api/login", self.login, methods=["POST"]),
            Route("/api/logout", self.logout, methods=["POST"]),
            Route("/api/me", self.me),
            Route("/api/status", self.status),
            Route("/api/control", self.control_action, methods=["POST"]),
            Route("/api/command", self.command, methods=["POST"]),
            Route("/api/openapi.json", lambda r: json_response(openapi_spec())),   # the API
            *self.camera.routes,
            WebSocketRoute("/ws", self.websocket),
            Mount("/static", StaticFiles(directory=STATIC), name="static"),
        ], middleware=[Middleware(SecurityHeaders),
                       Middleware(Gate, hosts=self.hosts, proxies=self.proxies,
                                  refused=self._host_refused)])

    # ------------------------------------------------------------------ the users file
    def hosts(self) -> frozenset[str]:
        self.tidy()
        return self._allowed

    def proxies(self) -> tuple[str, ...]:
        return self.settings.proxies

    def _host_refused(self, ip: str, why: str) -> None:
        self.record("request_refused", "-", ip=ip, why=why[:MAX_HOST_CHARS])

    def _reread(self) -> None:
        """The users file changed: new settings apply now; a release request is obeyed."""
        if not self.fixed_settings:
            try:
                st = Settings.of(self.users.section("settings"))
            except UsersError as e:
                print(f"feeder: operator UI: {e}; keeping the settings in force",
                      file=sys.stderr)
                st = self.settings
            self.settings = st
            self.sessions.idle_s, self.sessions.lifetime_s = st.session_idle_s, \
                st.session_lifetime_s
            self.control.grace_s = st.control_grace_s
            self._allowed = allowed_hosts(self.host, st.hosts)
        req = self.users.section("release_control")
        if req.get("seq") != self._release_seq:
            self._release_seq = req.get("seq")
            by = str(req.get("by", "?"))[:64]
            self.force_release(f"`feeder users release-control` by {by}")

    def force_release(self, by: str) -> Session | None:
        """An administrator frees control, whoever holds it; recorded either way."""
        holder, self.control.holder = self.control.holder, None
        self.record("control_released", holder.user if holder else "-", why=f"forced by {by}",
                    held=holder is not None)
        return holder

    # ------------------------------------------------------------------ sessions
    def tidy(self) -> None:
        """Housekeeping before every request and after every publish: end sessions that
        expired or whose user was removed or given a new password, free control whose
        holder has left, and obey a changed users file. Cheap: one stat when unchanged."""
        users = self.users.load_or_empty()
        if self.users.stamp != self._stamp:
            self._stamp = self.users.stamp
            self._reread()
        for s in self.sessions.prune():
            self._end(s, "expired", ended=True)
        for s in self.sessions.all():
            entry = users.get(s.user)
            secret = str(entry["hash"]) if entry else None
            if secret != s.secret:
                self._end(s, "user removed" if secret is None else "password changed")
        gone = self.control.expire()
        if gone is not None:
            self.record("control_released", gone.user,
                        why=f"no page open for {self.control.grace_s:g} s")

    def keeper(self, scope: dict[str, Any]) -> Callable[[], bool] | None:
        """For the connection gate: if this request or websocket is the session that
        holds control's, the test that it still does (its connection is then kept in
        the gate's reserve, never displaced by others' connections); else None. Runs on
        the loop before the app, so it must be cheap: a cookie and a comparison."""
        holder = self.control.holder
        if holder is None:
            return None
        token = HTTPConnection(scope).cookies.get(COOKIE) or ""
        if not secrets.compare_digest(token.encode(), holder.token.encode()):
            return None
        return lambda: (self.control.holder is not None
                        and self.control.holder.token == token)

    def session_of(self, conn: HTTPConnection) -> Session | None:
        """The caller's live session (this request counts as use), or None."""
        self.tidy()
        return self.sessions.get(conn.cookies.get(COOKIE))

    def watcher(self, conn: HTTPConnection) -> Session | None:
        """The caller's live session without counting this request as use (a page's
        polling, like the websocket's pushes, must not keep a forgotten tab alive)."""
        self.tidy()
        return self.sessions.peek(conn.cookies.get(COOKIE))

    def _end(self, s: Session, why: str, ended: bool = False) -> None:
        if not ended:
            self.sessions.end(s.token)
        self.record("session_ended", s.user, why=why)
        if self.control.drop(s.token):
            self.record("control_released", s.user, why=f"session ended ({why})")

    def note(self, user: str, action: str) -> None:
        """Log a login, logout or control change as an operator event (fire and forget)."""
        self.bridge.submit("note", {"action": action}, user)

    def session_info(self, s: Session) -> dict[str, Any]:
        return {"user": s.user, "control": self.control.state_for(s),
                "users": self.sessions.users(), "admin": self.users.role(s.user) == "admin"}

    def wake_all(self) -> None:
        """Called on the loop (after a publish, or a login/control change)."""
        self.tidy()
        for c in self.clients:
            c.wake.set()

    def _may_watch(self, request: Request) -> Response | None:
        """The tree view's polls: a logged-in user's, not counted as use (like a push)."""
        self.tidy()
        if self.sessions.peek(request.cookies.get(COOKIE)) is None:
            return refuse("not logged in", 401)
        return None

    # ------------------------------------------------------------------ pages
    async def index(self, request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={"cache-control": "no-store"})

    async def _body(self, request: Request) -> dict[str, Any] | Response:
        """The JSON object of a state-changing request, or the refusal to send back (one
        from another site recorded)."""
        if not same_origin(request):
            self.record("request_refused", "-", ip=client_ip(request), why="another site's Origin")
        return await json_body(request, MAX_BODY)

    async def _signed_in_body(self, request: Request
                              ) -> tuple[dict[str, Any], Session] | Response:
        """The body and session of a signed-in user's request, or the refusal to send."""
        body = await self._body(request)
        if isinstance(body, Response):
            return body
        s = self.session_of(request)
        if s is None:
            return refuse("not logged in", 401)
        return body, s

    # ------------------------------------------------------------------ login
    async def login(self, request: Request) -> Response:
        body = await self._body(request)
        if isinstance(body, Response):
            return body
        name, password = body.get("user"), body.get("password")
        if not isinstance(name, str) or not isinstance(password, str) or not name:
            return refuse("give a user name and a password", 400)
        real = NAME_RE.fullmatch(name) is not None
        known = request.cookies.get(KNOWN_COOKIE + name) if real else None
        attempt = Attempt(name[:64], client_ip(request), known)
        shown = name if real and self.users.exists(name) else "(unknown name)"
        verdict = self.guard.check(attempt)
        if verdict.wait_s > 0:
            secs = retry_after(verdict.wait_s)
            self.record("login_refused", shown, ip=attempt.ip, locked_by=verdict.why,
                        wait_s=secs)
            return refuse(f"too many failed logins: try again in {secs} s", 429,
                          {"retry-after": str(secs)})
        favoured = verdict.trusted or self.guard.known(attempt)
        if self._checking >= MAX_CHECKS or (not favoured
                                            and self._strangers >= STRANGER_CHECKS):
            return refuse("the controller is busy checking other logins: try again", 429,
                          {"retry-after": "1"})
        # one check in flight per address (a stranger) or per browser (a known one)
        if not self.guard.begin(attempt, verdict.trusted):
            return refuse("another login for this user is being checked: try again", 429,
                          {"retry-after": "1"})
        self._checking += 1
        self._strangers += 0 if favoured else 1
        try:
            entry = self.users.load_or_empty().get(name) if real else None
            stored = str(entry["hash"]) if entry else _dummy_hash()
            good = await run_in_threadpool(verify_password, password[:MAX_PASSWORD + 1],
                                           stored)
            good = good and entry is not None
        finally:
            self._checking -= 1
            self._strangers -= 0 if favoured else 1
            self.guard.end(attempt, verdict.trusted)
        if not good:
            locks = self.guard.failure(attempt, verdict.trusted)
            self.record("login_failed", shown, ip=attempt.ip, known_browser=verdict.trusted)
            for why, secs in locks:
                self.record("login_locked", shown, ip=attempt.ip, by=why,
                            seconds=round(secs, 1))
            lock = self.guard.check(attempt).wait_s
            more = f"; next attempt in {retry_after(lock)} s" if lock > 0 else ""
            return refuse(f"wrong user name or password{more}", 401)
        self.guard.success(attempt, verdict.trusted)
        s = self.sessions.create(name, attempt.ip, str(entry["hash"]))
        self.note(name, "logged in")
        self.wake_all()
        resp = json_response({"ok": True, **self.session_info(s)})
        set_login_cookies(resp, request, COOKIE, s.token, name, self.guard.issue(name))
        return resp

    async def logout(self, request: Request) -> Response:
        if not same_origin(request):
            self.record("request_refused", "-", ip=client_ip(request),
                        why="another site's Origin")
            return refuse("refused: request from another site", 403)
        s = self.session_of(request)
        if s is not None:
            if self.control.drop(s.token):
                self.note(s.user, "released control")
            self.sessions.end(s.token)
            self.note(s.user, "logged out")
            self.wake_all()
        resp = json_response({"ok": True})
        resp.delete_cookie(COOKIE, path="/", httponly=True, samesite="strict")
        return resp

    async def me(self, request: Request) -> Response:
        s = self.session_of(request)
        if s is None:
            return refuse("not logged in", 401)
        return json_response({"ok": True, **self.session_info(s)})

    async def status(self, request: Request) -> Response:
        """The latest snapshot as JSON (the page uses the websocket; this is for scripts)."""
        s = self.session_of(request)
        if s is None:
            return refuse("not logged in", 401)
        pub = self.bridge.latest()
        text = ('{"ok":true,"status":' + (pub.status_json if pub else "null")
                + ',"session":' + json.dumps(self.session_info(s)) + "}")
        return Response(text, media_type="application/json",
                        headers={"cache-control": "no-store"})

    # ------------------------------------------------------------------ control
    def _refused(self, s: Session, what: str, why: str) -> None:
        self.record("command_refused", s.user, command=what[:40], why=why[:200])

    async def control_action(self, request: Request) -> Response:
        got = await self._signed_in_body(request)
        if isinstance(got, Response):
            return got
        body, s = got
        action = body.get("action")
        if action == "take":
            ok, msg = self.control.take(s)
        elif action == "release":
            ok, msg = self.control.release(s)
        elif action == "force-release":
            if self.users.role(s.user) != "admin":
                self._refused(s, "force-release", "not an admin")
                return refuse("refused: only an admin may force control free", 403)
            if self.control.holder is None:
                ok, msg = False, "nobody has control"
            else:
                holder = self.force_release(f"admin {s.user}")
                ok, msg = True, f"control taken from {holder.user if holder else '-'}"
        else:
            return refuse("action must be \"take\", \"release\" or \"force-release\"", 400)
        if ok:
            if action != "force-release":
                self.note(s.user, "took control" if action == "take" else "released control")
            self.wake_all()
        else:
            self._refused(s, f"{action} control", msg)
        return json_response({"ok": ok, "message" if ok else "error": msg,
                      **self.session_info(s)}, 200 if ok else 409)

    async def command(self, request: Request) -> Response:
        """An operator command: only from the holder of control; run on the tick thread."""
        got = await self._signed_in_body(request)
        if isinstance(got, Response):
            return got
        body, s = got
        name = body.pop("command", None)
        if name not in COMMANDS:
            self._refused(s, repr(name), "unknown command")
            return refuse(f"unknown command {str(name)[:40]!r} (one of: "
                           f"{', '.join(COMMANDS)})", 400)
        if not self.control.is_holder(s):
            msg = self.control.refusal(s)
            self._refused(s, name, msg)
            return refuse(msg, 403)
        out = await self.call(name, body, s.user)
        if not out.ok:
            self._refused(s, name, out.message)
        return json_response({"ok": out.ok, "message" if out.ok else "error": out.message}, out.status)

    async def call(self, name: str, args: dict[str, Any], user: str) -> Outcome:
        """Submit to the tick thread and wait; a command not started in time is withdrawn
        (it will never run), one already running is waited for."""
        fut = self.bridge.submit(name, args, user)
        afut = asyncio.wrap_future(fut)
        try:
            return await asyncio.wait_for(asyncio.shield(afut), COMMAND_TIMEOUT_S)
        except TimeoutError:
            if fut.cancel():
                return Outcome.refused(f"the cell did not answer within {COMMAND_TIMEOUT_S:g} "
                                       "s; nothing was changed", 503)
            return await afut

    # ------------------------------------------------------------------ websocket
    async def websocket(self, ws: WebSocket) -> None:
        if not same_origin(ws):
            self.record("request_refused", "-", ip=client_ip(ws), why="another site's Origin")
            await ws.close(code=1008)
            return
        s = self.session_of(ws)
        if s is None:
            await ws.close(code=4401)
            return
        await ws.accept()
        client = _Client(ws, s.token)
        self.clients.add(client)
        s.conns += 1                         # the holder is here: control stays
        client.wake.set()
        sender = asyncio.create_task(self._send_loop(client))
        try:
            while True:              # the page sends nothing we need; wait for the close
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
        except (WebSocketDisconnect, RuntimeError):
            pass
        finally:
            self.clients.discard(client)
            sender.cancel()
            s.conns -= 1
            s.left = self.sessions.clock()
            self.wake_all()                  # the others see "control free in N s"

    def update_for(self, client: _Client, s: Session) -> str | None:
        """The next message for one client: the latest status, the chart points and
        messages it has not had, and its own view of sessions and control; None if it
        has had all that already."""
        pub = self.bridge.latest()
        session = json.dumps(self.session_info(s))
        seq = pub.seq if pub is not None else -1
        if seq == client.pub_seq and session == client.session:
            return None
        client.pub_seq, client.session = seq, session
        parts = ['{"type":"update","session":', session]
        if pub is not None:
            hist = [h for h in pub.history if h[0] > client.hist_t]
            msgs = [{"seq": m.seq, "t": m.t, "kind": m.kind, "text": m.text}
                    for m in pub.messages if m.seq > client.msg_seq]
            if hist:
                client.hist_t = hist[-1][0]
            if msgs:
                client.msg_seq = msgs[-1]["seq"]
            parts += [',"status":', pub.status_json, ',"history":', json.dumps(hist),
                      ',"messages":', json.dumps(msgs)]
        parts.append("}")
        return "".join(parts)

    async def _send_loop(self, client: _Client) -> None:
        ws = client.ws
        while True:
            await client.wake.wait()
            client.wake.clear()              # wake_all() has tidied the sessions
            s = self.sessions.peek(client.token)     # a push is not a request: no refresh
            if s is None:
                await _bounded(ws.send_text('{"type":"logout"}'))
                await _bounded(ws.close(code=4401))
                return
            text = self.update_for(client, s)
            if text is None:
                continue
            if not await _bounded(ws.send_text(text), SEND_TIMEOUT_S):
                self.clients.discard(client)            # too slow or gone: drop it
                await _bounded(ws.close(code=1013))
                return


async def _bounded(aw: Awaitable[Any], timeout: float = 1.0) -> bool:
    """Await a send or close for at most ``timeout``; False if it failed or took longer."""
    try:
        await asyncio.wait_for(aw, timeout)
        return True
    except Exception:
        return False
