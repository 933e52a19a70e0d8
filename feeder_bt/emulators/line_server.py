"""One client at a time on a loopback socket, its bytes cut into lines: the serving loop of
the emulators that answer a line at a time (the AnyFeeder's, the camera server's). The
Galil and V+ emulators keep their own: several handles at once, each controller's framing.

``accept`` and ``recv`` wait at most ``POLL_S`` before looking at the stop flag again:
closing the listening socket from ``stop`` does not wake an ``accept`` blocked in another
thread (Linux), so without the poll ``stop`` would wait out its whole join time-out.
"""

from __future__ import annotations

import select
import socket
import threading
from typing import Self

POLL_S = 0.1        # how often the server's thread looks at the stop flag


class LineServer:
    """Listens on ``host``:``port`` from construction (0: any free port; ``.port`` says
    which); ``start`` serves in a thread, ``stop`` ends it. A subclass answers each line
    (without its ``terminator``) in ``on_line``; a client that has gone ends its session."""

    terminator = b"\n"
    thread_name = "line-server"
    #: a new client takes the line from the one being served: a serial line behind a
    #: socket has no sessions, the device hears whoever writes (the AnyFeeder's RS-232)
    displace = False

    def __init__(self, host: str = "127.0.0.1", port: int = 0) -> None:
        self.host = host
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind((host, port))
        self._sock.listen(1)
        self._sock.settimeout(POLL_S)
        self.port: int = self._sock.getsockname()[1]
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> Self:
        self._thread = threading.Thread(target=self._serve, name=self.thread_name,
                                        daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        try:
            self._sock.close()
        except OSError:
            pass

    def on_line(self, conn: socket.socket, line: bytes) -> None:
        raise NotImplementedError

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                self._session(conn)

    def _session(self, conn: socket.socket) -> None:
        conn.settimeout(POLL_S)
        buf = b""
        end = self.terminator
        while not self._stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                if self.displace and select.select([self._sock], [], [], 0)[0]:
                    return                   # a newer client is waiting: it has the line
                continue
            except OSError:
                return
            if not data:
                return
            buf += data
            while end in buf:
                line, buf = buf.split(end, 1)
                try:
                    self.on_line(conn, line)
                except OSError:              # the client went while it was answered
                    return
