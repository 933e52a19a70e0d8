"""The operator UI's web server: a Starlette app run by uvicorn in a background thread.

Threading: the app runs on its own asyncio loop in the ``feeder-ui`` thread and never
touches the cell. It reads the bridge's latest published snapshot and submits commands
to the bridge; the tick thread wakes it with ``loop.call_soon_threadsafe`` after each
publish. Each websocket client has a sender task that always sends the *latest* snapshot
(updates published while it was busy are coalesced), and a client that cannot take one
within ``SEND_TIMEOUT_S`` is dropped; the cell never waits on any of this.

Security: passwords are checked against the users file's scrypt hashes off the loop;
failed logins are rate-limited; the session token lives only in an HTTP-only,
``SameSite=Strict`` cookie; state-changing requests must be JSON from the page's own
origin (a cross-site form or script cannot send them); the page is served with a strict
Content-Security-Policy (no inline script, nothing from elsewhere).
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import socket
import threading
import time
from collections.abc import Awaitable
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.middleware import Middleware
from starlette.requests import HTTPConnection, Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.types import ASGIApp, Message, Receive, Scope, Send
from starlette.websockets import WebSocket, WebSocketDisconnect

from ..errors import FeederError
from .bridge import Bridge, Outcome
from .control import Control, LoginLimiter, Session, Sessions, retry_after
from .operate import COMMANDS
from .users import MAX_PASSWORD, NAME_RE, UsersFile, _dummy_hash, verify_password

COOKIE = "feeder_session"
COMMAND_TIMEOUT_S = 5.0       # the tick thread answers within a tick or two; else 503
SEND_TIMEOUT_S = 5.0          # a websocket client slower than this is dropped
MAX_BODY = 64 * 1024          # bytes: every request the page makes is a few hundred
STATIC = Path(__file__).parent / "static"

SECURITY_HEADERS = [
    (b"content-security-policy",
     b"default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
     b"connect-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"no-referrer"),
    (b"x-frame-options", b"DENY"),
]


class _SecurityHeaders:
    """Adds ``SECURITY_HEADERS`` to every HTTP response (pages, assets and the API)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        async def send_with_headers(message: Message) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []),
                                                  *SECURITY_HEADERS]}
            await send(message)

        await self.app(scope, receive, send_with_headers)


class _Client:
    """One open websocket: what it has been sent so far."""

    def __init__(self, ws: WebSocket, token: str) -> None:
        self.ws, self.token = ws, token
        self.wake = asyncio.Event()
        self.hist_t = -1.0
        self.msg_seq = 0
        self.pub_seq = -1                # the snapshot and session view last sent
        self.session = ""


def _same_origin(conn: HTTPConnection) -> bool:
    """A browser always sends ``Origin`` on POSTs and websockets; it must be this server.
    (A client without one, such as curl, is not a browser that a third site can drive.)"""
    origin = conn.headers.get("origin")
    if origin is None:
        return True
    return urlsplit(origin).netloc.lower() == conn.headers.get("host", "").lower()


def _json(data: Any, status: int = 200, headers: dict[str, str] | None = None) -> Response:
    return JSONResponse(data, status_code=status,
                        headers={"cache-control": "no-store", **(headers or {})})


def _refuse(message: str, status: int, headers: dict[str, str] | None = None) -> Response:
    return _json({"ok": False, "error": message}, status, headers)


class UiApp:
    """The web side's state (sessions, control, limiter, websocket clients) and routes."""

    def __init__(self, bridge: Bridge, users: UsersFile, *, sessions: Sessions | None = None,
                 control: Control | None = None, limiter: LoginLimiter | None = None) -> None:
        self.bridge, self.users = bridge, users
        self.sessions = sessions or Sessions()
        self.control = control or Control()
        self.limiter = limiter or LoginLimiter()
        self.clients: set[_Client] = set()
        _dummy_hash()                    # computed now, not on the loop at the first login
        self.app = Starlette(routes=[
            Route("/", self.index),
            Route("/api/login", self.login, methods=["POST"]),
            Route("/api/logout", self.logout, methods=["POST"]),
            Route("/api/me", self.me),
            Route("/api/status", self.status),
            Route("/api/control", self.control_action, methods=["POST"]),
            Route("/api/command", self.command, methods=["POST"]),
            WebSocketRoute("/ws", self.websocket),
            Mount("/static", StaticFiles(directory=STATIC), name="static"),
        ], middleware=[Middleware(_SecurityHeaders)])

    # ------------------------------------------------------------------ sessions
    def session_of(self, conn: HTTPConnection) -> Session | None:
        """The caller's live session; a session whose user was removed ends here."""
        s = self.sessions.get(conn.cookies.get(COOKIE))
        if s is not None and not self.users.exists(s.user):
            self._end(s)
            return None
        return s

    def _end(self, s: Session) -> None:
        self.sessions.end(s.token)
        if self.control.drop(s.token):
            self.note(s.user, "lost control (session ended)")
        self.wake_all()

    def note(self, user: str, action: str) -> None:
        """Log a login, logout or control change as an operator event (fire and forget)."""
        self.bridge.submit("note", {"action": action}, user)

    def session_info(self, s: Session) -> dict[str, Any]:
        return {"user": s.user, "control": self.control.state_for(s),
                "users": self.sessions.users()}

    def wake_all(self) -> None:
        """Called on the loop (after a publish, or a login/control change)."""
        for s in self.sessions.prune():
            if self.control.drop(s.token):
                self.note(s.user, "lost control (session expired)")
        for c in self.clients:
            c.wake.set()

    # ------------------------------------------------------------------ pages
    async def index(self, request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={"cache-control": "no-store"})

    async def _body(self, request: Request) -> dict[str, Any] | Response:
        """The JSON object of a state-changing request, or the refusal to send back."""
        if not _same_origin(request):
            return _refuse("refused: request from another site", 403)
        if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
            return _refuse("expected a JSON body (Content-Type: application/json)", 415)
        raw = b""
        async for chunk in request.stream():
            raw += chunk
            if len(raw) > MAX_BODY:
                return _refuse("request too large", 413)
        try:
            body = json.loads(raw or b"{}")
        except (json.JSONDecodeError, UnicodeDecodeError):
            return _refuse("the body is not valid JSON", 400)
        if not isinstance(body, dict):
            return _refuse("the body must be a JSON object", 400)
        return body

    async def _signed_in_body(self, request: Request
                              ) -> tuple[dict[str, Any], Session] | Response:
        """The body and session of a signed-in user's request, or the refusal to send."""
        body = await self._body(request)
        if isinstance(body, Response):
            return body
        s = self.session_of(request)
        if s is None:
            return _refuse("not logged in", 401)
        return body, s

    # ------------------------------------------------------------------ login
    async def login(self, request: Request) -> Response:
        body = await self._body(request)
        if isinstance(body, Response):
            return body
        name, password = body.get("user"), body.get("password")
        if not isinstance(name, str) or not isinstance(password, str) or not name:
            return _refuse("give a user name and a password", 400)
        ip = request.client.host if request.client else "?"
        keys = (f"user:{name.lower()[:64]}", f"ip:{ip}")
        wait = self.limiter.locked_for(keys)
        if wait > 0:
            secs = retry_after(wait)
            return _refuse(f"too many failed logins: try again in {secs} s", 429,
                           {"retry-after": str(secs)})
        if not self.limiter.begin(keys):
            return _refuse("another login for this user is being checked: try again", 429,
                           {"retry-after": "1"})
        try:
            entry = self.users.load_or_empty().get(name) if NAME_RE.fullmatch(name) else None
            stored = str(entry["hash"]) if entry else _dummy_hash()
            good = await run_in_threadpool(verify_password, password[:MAX_PASSWORD + 1],
                                           stored)
            good = good and entry is not None
        finally:
            self.limiter.end(keys)
        if not good:
            lock = self.limiter.failure(keys)
            more = (f"; next attempt in {retry_after(lock)} s" if lock > 0 else "")
            return _refuse(f"wrong user name or password{more}", 401)
        self.limiter.success(keys)
        s = self.sessions.create(name, ip)
        self.note(name, "logged in")
        self.wake_all()
        resp = _json({"ok": True, **self.session_info(s)})
        resp.set_cookie(COOKIE, s.token, httponly=True, samesite="strict", path="/",
                        secure=request.url.scheme == "https")
        return resp

    async def logout(self, request: Request) -> Response:
        if not _same_origin(request):
            return _refuse("refused: request from another site", 403)
        s = self.session_of(request)
        if s is not None:
            if self.control.drop(s.token):
                self.note(s.user, "released control")
            self.sessions.end(s.token)
            self.note(s.user, "logged out")
            self.wake_all()
        resp = _json({"ok": True})
        resp.delete_cookie(COOKIE, path="/", httponly=True, samesite="strict")
        return resp

    async def me(self, request: Request) -> Response:
        s = self.session_of(request)
        if s is None:
            return _refuse("not logged in", 401)
        return _json({"ok": True, **self.session_info(s)})

    async def status(self, request: Request) -> Response:
        """The latest snapshot as JSON (the page uses the websocket; this is for scripts)."""
        s = self.session_of(request)
        if s is None:
            return _refuse("not logged in", 401)
        pub = self.bridge.latest()
        text = ('{"ok":true,"status":' + (pub.status_json if pub else "null")
                + ',"session":' + json.dumps(self.session_info(s)) + "}")
        return Response(text, media_type="application/json",
                        headers={"cache-control": "no-store"})

    # ------------------------------------------------------------------ control
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
        else:
            return _refuse("action must be \"take\" or \"release\"", 400)
        if ok:
            self.note(s.user, "took control" if action == "take" else "released control")
            self.wake_all()
        return _json({"ok": ok, "message" if ok else "error": msg,
                      **self.session_info(s)}, 200 if ok else 409)

    async def command(self, request: Request) -> Response:
        """An operator command: only from the holder of control; run on the tick thread."""
        got = await self._signed_in_body(request)
        if isinstance(got, Response):
            return got
        body, s = got
        name = body.pop("command", None)
        if name not in COMMANDS:
            return _refuse(f"unknown command {name!r} (one of: {', '.join(COMMANDS)})", 400)
        if not self.control.is_holder(s):
            return _refuse(self.control.refusal(s), 403)
        out = await self.call(name, body, s.user)
        return _json({"ok": out.ok, "message" if out.ok else "error": out.message}, out.status)

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
        if not _same_origin(ws):
            await ws.close(code=1008)
            return
        s = self.session_of(ws)
        if s is None:
            await ws.close(code=4401)
            return
        await ws.accept()
        client = _Client(ws, s.token)
        self.clients.add(client)
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
            client.wake.clear()
            s = self.sessions.get(client.token)
            if s is None or not self.users.exists(s.user):
                if s is not None:
                    self._end(s)
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


# ---------------------------------------------------------------------------- the thread


def _bind(host: str, port: int) -> socket.socket:
    """Bind in the caller's thread, so a bad address or a busy port is a one-line error
    before the cell starts (and port 0 can be resolved to the port the system chose)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
        family, _, _, _, addr = infos[0]
        sock = socket.socket(family, socket.SOCK_STREAM)
    except (OSError, IndexError) as e:
        raise FeederError(f"--ui {host}:{port}: cannot use this address: {e}") from None
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(addr)
        sock.listen(64)
    except OSError as e:
        sock.close()
        raise FeederError(f"--ui {host}:{port}: cannot listen: {e.strerror}") from None
    sock.setblocking(False)
    return sock


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class UiServer:
    """uvicorn serving a ``UiApp`` in a daemon thread with its own event loop."""

    def __init__(self, ui: UiApp, host: str, port: int) -> None:
        self.ui, self.host, self.port = ui, host, port
        self._sock: socket.socket | None = None
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}/"

    def start(self, timeout: float = 10.0) -> str:
        """Bind, start the thread, wait until it serves; returns the URL."""
        import uvicorn

        self._sock = _bind(self.host, self.port)
        self.port = self._sock.getsockname()[1]
        config = uvicorn.Config(self.ui.app, log_level="warning", access_log=False,
                                lifespan="off", timeout_graceful_shutdown=2,
                                ws_ping_interval=10.0, ws_ping_timeout=10.0,
                                ws_max_size=64 * 1024)
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._run, name="feeder-ui", daemon=True)
        self._thread.start()
        end = time.monotonic() + timeout
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > end:
                self.close()
                raise FeederError(f"operator UI on {self.url} did not start"
                                  + (f": {self._error}" if self._error else ""))
            time.sleep(0.01)
        return self.url

    def _run(self) -> None:
        try:
            asyncio.run(self._main())
        except BaseException as e:       # reported by start(), or lost at shutdown
            self._error = e

    async def _main(self) -> None:
        loop = asyncio.get_running_loop()

        def notify() -> None:            # tick thread: hop onto our loop, never block
            loop.call_soon_threadsafe(self.ui.wake_all)

        self.ui.bridge.subscribe(notify)
        try:
            await self._server.serve(sockets=[self._sock])
        finally:
            self.ui.bridge.unsubscribe(notify)

    def close(self, timeout: float = 5.0) -> None:
        """Ask uvicorn to stop (websockets are closed) and wait for the thread."""
        if self._server is not None:
            self._server.should_exit = True
        if self._thread is not None:
            self._thread.join(timeout)
            if self._thread.is_alive():
                self._server.force_exit = True
                self._thread.join(1.0)
        if self._sock is not None:
            self._sock.close()


def make_notice(host: str) -> str | None:
    """A warning when the UI is reachable from other machines over plain HTTP."""
    if is_loopback(host):
        return None
    return (f"feeder: warning: the operator UI on {host} is reachable from the network over "
            "plain HTTP: passwords and session cookies travel unencrypted (serve it on "
            "127.0.0.1 behind a TLS proxy instead)")

