"""Playing the attacker on loopback: many idle TCP connections from many
loopback addresses (127.0.N.x: every 127/8 address is this machine on Linux), opened
without blocking and held until closed. Shared by tests/ui/test_conn_limits.py and
benchmarks/flood.py."""

from __future__ import annotations

import errno
import resource
import selectors
import socket
import time


def raise_fd_limit(need: int) -> int:
    """Raise this process's soft limit on open files to at least ``need`` if the hard
    limit allows; returns the soft limit now."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < need:
        target = need if hard == resource.RLIM_INFINITY else min(need, hard)
        resource.setrlimit(resource.RLIMIT_NOFILE, (target, hard))
        soft = target
    return soft


class IdleFlood:
    """``n`` connections to ``(host, port)`` that never send a byte, spread over
    ``addresses`` source addresses 127.<net>.0.1, 127.<net>.0.2, ..."""

    def __init__(self, port: int, n: int, addresses: int = 50, net: int = 1,
                 host: str = "127.0.0.1") -> None:
        raise_fd_limit(2 * n + 512)
        self.socks: list[socket.socket] = []
        self.sel = selectors.DefaultSelector()
        for i in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.setblocking(False)
            s.bind((f"127.{net}.{i % addresses // 250}.{i % addresses % 250 + 1}", 0))
            err = s.connect_ex((host, port))
            if err not in (0, errno.EINPROGRESS):
                s.close()
                continue
            self.socks.append(s)
            self.sel.register(s, selectors.EVENT_WRITE)

    def settle(self, timeout_s: float = 60.0) -> int:
        """Wait until every connect has finished (made, refused or reset) or ``timeout_s``
        passed; returns how many finished."""
        done = 0
        end = time.monotonic() + timeout_s
        while done < len(self.socks) and time.monotonic() < end:
            for key, _ in self.sel.select(timeout=0.5):
                self.sel.unregister(key.fileobj)
                done += 1
        return done

    def still_open(self) -> int:
        """Connections the server has not closed (a peek reads nothing and no EOF)."""
        n = 0
        for s in self.socks:
            try:
                if s.recv(1, socket.MSG_PEEK) == b"":
                    continue
            except BlockingIOError:
                n += 1
            except OSError:
                continue
        return n

    def close(self) -> None:
        self.sel.close()
        for s in self.socks:
            s.close()
        self.socks.clear()


class ReopeningFlood:
    """``n`` idle connections from one address (``source``, 127.0.0.1 by default: the
    operator's own, or a reverse proxy's) that are opened again as soon as the server
    closes them, by a background thread, until ``close()``. ``reopened`` counts them."""

    def __init__(self, port: int, n: int = 40, source: str = "127.0.0.1",
                 host: str = "127.0.0.1") -> None:
        import threading
        raise_fd_limit(4 * n + 512)
        self.port, self.n, self.source, self.host = port, n, source, host
        self.reopened = 0
        self.sel = selectors.DefaultSelector()
        self._stop = threading.Event()
        for _ in range(n):
            self._open()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _open(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setblocking(False)
        s.bind((self.source, 0))
        s.connect_ex((self.host, self.port))
        self.sel.register(s, selectors.EVENT_READ)

    def _run(self) -> None:
        while not self._stop.is_set():
            for key, _ in self.sel.select(timeout=0.1):
                s = key.fileobj
                try:
                    data = s.recv(4096)          # type: ignore[union-attr]
                except BlockingIOError:
                    continue
                except OSError:
                    data = b""
                if data:
                    continue                      # an answer (a 503, a close line): ignore
                self.sel.unregister(s)
                s.close()                         # type: ignore[union-attr]
                if not self._stop.is_set():
                    self._open()
                    self.reopened += 1

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5.0)
        for key in list(self.sel.get_map().values()):
            key.fileobj.close()                   # type: ignore[union-attr]
        self.sel.close()


class IdleWebsockets:
    """``n`` websockets of one signed-in user (``cookie``) to ``url`` that send nothing
    (the server's pushes are read and dropped), opened again as the server closes them,
    by a background thread, until ``close()``."""

    def __init__(self, url: str, cookie: str, n: int = 32,
                 headers: dict[str, str] | None = None) -> None:
        import threading
        self.url, self.cookie, self.n = url, cookie, n
        self.extra = "".join(f"{k}: {v}\r\n" for k, v in (headers or {}).items())
        self.socks: list[socket.socket] = []
        self.reopened = 0
        self._stop = threading.Event()
        for _ in range(n):
            self.socks.append(self._open())
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _open(self) -> socket.socket:
        """A websocket handshake by hand on a plain socket, then silence."""
        import base64
        import os
        from urllib.parse import urlsplit
        u = urlsplit(self.url)
        s = socket.create_connection((u.hostname, u.port), timeout=10)
        key = base64.b64encode(os.urandom(16)).decode()
        s.sendall((f"GET {u.path or '/'} HTTP/1.1\r\nHost: {u.hostname}:{u.port}\r\n"
                   f"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
                   f"Sec-WebSocket-Version: 13\r\nCookie: {self.cookie}\r\n{self.extra}\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = s.recv(4096)
            if not chunk:
                break
            head += chunk
        s.setblocking(False)
        return s

    def open_count(self) -> int:
        return sum(1 for s in self.socks if s.fileno() >= 0)

    def _run(self) -> None:
        while not self._stop.is_set():
            for i, s in enumerate(self.socks):
                try:
                    while s.recv(65536):           # pushes: dropped
                        pass
                except BlockingIOError:
                    continue                       # still open
                except OSError:
                    pass
                s.close()
                if self._stop.is_set():
                    return
                try:
                    self.socks[i] = self._open()
                    self.reopened += 1
                except OSError:
                    pass
            self._stop.wait(0.05)

    def close(self) -> None:
        self._stop.set()
        self.thread.join(5.0)
        for s in self.socks:
            s.close()
