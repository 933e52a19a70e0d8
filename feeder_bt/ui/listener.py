"""The operator UI's thread: uvicorn serving a ``UiApp`` on its own asyncio loop.

The socket is bound in the caller's thread, so a bad address or a busy port is a one-line
error before the cell starts. uvicorn's own forwarded-header handling is off: only
``access.Gate`` decides whose ``X-Forwarded-*`` headers count (a named proxy's).

Connections: uvicorn caps only concurrency in all (``limit_concurrency``, which idle
connections fill too) and closes a connection only after a response
(``timeout_keep_alive``); a connection that never sends a request is never closed. So its
HTTP and websocket protocol classes are replaced (``Config(http=..., ws=...)``) by
subclasses that pass each connection through a ``conns.ConnGate`` (per-address and total
caps, the oldest idle connection or idle websocket closed for a newcomer) and close one
whose request has not arrived within ``header_s``. Each request and websocket is shown to
``keeper`` (the dashboard's: is this the session that holds control?): a connection it
vouches for goes into the gate's reserve and is never displaced, and one let in on trial
(every capped connection busy) is answered 503 and closed unless it is vouched for; header size stays bounded by h11's
``h11_max_incomplete_event_size`` (16 KiB); the backlog is the system's ceiling. (uvicorn
docs, "Settings" — ``limit_concurrency``, ``backlog``, ``timeout_keep_alive``,
``h11_max_incomplete_event_size`` — and "Server Behavior"; checked against uvicorn 0.54's
``protocols/http/h11_impl.py``, whose keep-alive timer starts only after a response.)
"""

from __future__ import annotations

import asyncio
import ipaddress
import socket
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from feeder_bt.control.conns import ConnGate, ConnLimits, backlog, quiet_logger
from feeder_bt.core.errors import FeederError

if TYPE_CHECKING:
    from feeder_bt.ui.server import UiApp


#: the dashboard's: a browser opens ~6 connections and a websocket; the holder of
#: control has 16 more outside the caps (her page, a script, a retry)
UI_LIMITS = ConnLimits(total=512, per_address=32, reserve=16)


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
        sock.listen(backlog())           # a burst waits in the kernel
    except OSError as e:
        sock.close()
        raise FeederError(f"--ui {host}:{port}: cannot listen: {e.strerror}") from None
    sock.setblocking(False)
    return sock


#: given a request's ASGI scope, a callable saying whether its connection is still to be
#: kept (the session that holds control still holds it), or None if it is nobody's
Keeper = Callable[[dict[str, Any]], "Callable[[], bool] | None"]
BUSY_BODY = b'{"ok":false,"error":"the controller is busy: try again"}'


def _screened(app: Any, gate: ConnGate, keeper: Keeper | None,
              transport: Callable[[], Any]) -> Any:
    """``app`` behind the reserve's door: a request ``keeper`` vouches for puts its
    connection in the gate's reserve; one on trial that it does not vouch for is
    refused (503, or a websocket closed 1013) and its connection closed."""

    async def screened(scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] in ("http", "websocket"):
            t = transport()
            kept = keeper(scope) if keeper is not None else None
            if kept is not None:
                gate.vouch(t, kept)
            elif gate.on_trial(t):
                gate.note("closed: a connection on trial was not the holder of control's")
                if scope["type"] == "websocket":
                    await send({"type": "websocket.close", "code": 1013})
                else:
                    await send({"type": "http.response.start", "status": 503,
                                "headers": [(b"content-type", b"application/json"),
                                            (b"retry-after", b"1"),
                                            (b"connection", b"close")]})
                    await send({"type": "http.response.body", "body": BUSY_BODY})
                return
            else:
                gate.unkeep(t)
        await app(scope, receive, send)

    return screened


def gated_protocols(gate: ConnGate, keeper: Keeper | None = None
                    ) -> tuple[type, type | None]:
    """uvicorn's HTTP (h11) and websocket protocol classes, admitting each connection
    through ``gate``, closing one whose next request has not come within
    ``gate.limits.header_s`` (after the connection is made, and after each response), and
    showing each request to ``keeper`` (``_screened``)."""
    from uvicorn.protocols.http.h11_impl import H11Protocol
    from uvicorn.protocols.websockets.auto import AutoWebSocketsProtocol

    header_s = gate.limits.header_s

    class GatedHttp(H11Protocol):
        _feeder_in = False

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            super().__init__(*args, **kwargs)
            self.app = _screened(self.app, gate, keeper, lambda: self.transport)

        def connection_made(self, transport: Any) -> None:  # type: ignore[override]
            if not gate.admit(transport, self._busy):
                return                            # aborted: connection_lost does nothing
            self._feeder_in = True
            super().connection_made(transport)
            self._arm()

        def _busy(self) -> bool:
            return self.cycle is not None and not self.cycle.response_complete

        def _arm(self) -> None:
            armed = self.cycle
            self.loop.call_later(header_s, self._deadline, armed)

        def _deadline(self, armed: Any) -> None:
            if self.cycle is armed and not self._busy() and not self.transport.is_closing() \
                    and self.transport.get_protocol() is self:
                gate.note(f"closed: no request within {header_s:g} s")
                self.transport.close()

        def on_response_complete(self) -> None:
            super().on_response_complete()
            if not self.transport.is_closing():
                self._arm()

        def connection_lost(self, exc: Exception | None) -> None:
            if not self._feeder_in:
                return
            if self.transport.get_protocol() is self:
                gate.release(self.transport)
            super().connection_lost(exc)

    ws_class = None
    if AutoWebSocketsProtocol is not None:
        class GatedWs(AutoWebSocketsProtocol):  # type: ignore[misc, valid-type]
            def __init__(self, *args: Any, **kwargs: Any) -> None:
                super().__init__(*args, **kwargs)
                self.app = _screened(self.app, gate, keeper, lambda: self.transport)

            def connection_made(self, transport: Any) -> None:  # type: ignore[override]
                # an open websocket is idle: displaceable unless the keeper vouches for it
                gate.replace(transport, lambda: False)
                super().connection_made(transport)

            def connection_lost(self, exc: Exception | None) -> None:
                gate.release(self.transport)
                super().connection_lost(exc)

        ws_class = GatedWs
    return GatedHttp, ws_class


def uvicorn_config(app: Any, gate: ConnGate, keeper: Keeper | None = None,
                   **extra: Any) -> Any:
    """The uvicorn settings every feeder web listener uses (dashboard, replay)."""
    import uvicorn
    http, ws = gated_protocols(gate, keeper)
    return uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off",
                          proxy_headers=False, server_header=False, http=http,
                          **({"ws": ws} if ws is not None else {}),
                          timeout_keep_alive=5, h11_max_incomplete_event_size=16 * 1024,
                          backlog=backlog(), **extra)


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


class UiServer:
    """uvicorn serving a ``UiApp`` in a daemon thread with its own event loop."""

    def __init__(self, ui: UiApp, host: str, port: int,
                 limits: ConnLimits | None = None) -> None:
        self.ui, self.host, self.port = ui, host, port
        self.gate = ConnGate("operator UI", limits or UI_LIMITS)
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
        config = uvicorn_config(self.ui.app, self.gate, self.ui.keeper,
                                timeout_graceful_shutdown=2,
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
        self.gate.loop_errors(loop)
        unquiet = quiet_logger("uvicorn.error", self.gate)

        def notify() -> None:            # tick thread: hop onto our loop, never block
            loop.call_soon_threadsafe(self.ui.wake_all)

        self.ui.bridge.subscribe(notify)
        try:
            await self._server.serve(sockets=[self._sock])
        finally:
            self.ui.bridge.unsubscribe(notify)
            unquiet()

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


def make_notice(host: str, what: str = "the operator UI") -> str | None:
    """A warning when the UI is reachable from other machines over plain HTTP."""
    if is_loopback(host):
        return None
    if host.strip("[]") in ("", "0.0.0.0", "::"):
        return (f"feeder: warning: {what} listens on every address ({host}) over "
                "plain HTTP, and answers only to localhost until you name this machine: "
                "`feeder users set hosts NAME...` (serve it on 127.0.0.1 behind a TLS proxy "
                "instead)")
    return (f"feeder: warning: {what} on {host} is reachable from the network over "
            "plain HTTP: passwords and session cookies travel unencrypted (serve it on "
            "127.0.0.1 behind a TLS proxy instead)")

