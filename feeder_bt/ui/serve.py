"""The operator UI's thread: uvicorn serving a ``UiApp`` on its own asyncio loop.

The socket is bound in the caller's thread, so a bad address or a busy port is a one-line
error before the cell starts. uvicorn's own forwarded-header handling is off: only
``access.Gate`` decides whose ``X-Forwarded-*`` headers count (a named proxy's).
"""

from __future__ import annotations

import asyncio
import ipaddress
import socket
import threading
import time
from typing import TYPE_CHECKING, Any

from ..errors import FeederError

if TYPE_CHECKING:
    from .server import UiApp


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
                                proxy_headers=False, server_header=False,
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
    if host.strip("[]") in ("", "0.0.0.0", "::"):
        return (f"feeder: warning: the operator UI listens on every address ({host}) over "
                "plain HTTP, and answers only to localhost until you name this machine: "
                "`feeder users set hosts NAME...` (serve it on 127.0.0.1 behind a TLS proxy "
                "instead)")
    return (f"feeder: warning: the operator UI on {host} is reachable from the network over "
            "plain HTTP: passwords and session cookies travel unencrypted (serve it on "
            "127.0.0.1 behind a TLS proxy instead)")

