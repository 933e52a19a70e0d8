"""TCP clients of the V+ server programs: one socket per server, one worker per socket.

The thesis's monitor: each socket has a single-thread executor, so requests go out one at
a time, in order, and each waits for its reply before the next is sent. The tick never
waits on a socket; it only gets ``Future``s (wrapped in jobs by ``robot.py``).

A dropped connection fails the request in flight with ``CommsLost``; the next request
re-connects, backing off 0.1 s, 0.2 s, ... up to 2 s between attempts while the server
is away (the V+ servers reset their socket and wait for a new client, Figure 7-1).
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor

from feeder_bt.core.errors import CommsLost
from feeder_bt.hal.adept import protocol
from feeder_bt.hal.adept.protocol import Command, GarbledReply, ProtocolError

BACKOFF_MIN_S = 0.1
BACKOFF_MAX_S = 2.0


class Backoff:
    """When the next connection attempt may be made: 0.1 s, doubling to 2 s."""

    def __init__(self, first: float = BACKOFF_MIN_S, limit: float = BACKOFF_MAX_S) -> None:
        self.first, self.limit = first, limit
        self.delay = first
        self.next_try = 0.0

    def failed(self, now: float) -> None:
        self.next_try = now + self.delay
        self.delay = min(self.limit, self.delay * 2)

    def dropped(self, now: float) -> None:
        """The link was lost: wait the first step before trying again."""
        self.delay = self.first
        self.failed(now)

    def succeeded(self) -> None:
        self.delay = self.first
        self.next_try = 0.0


class LineSocket:
    """A line-oriented TCP connection that re-connects with back-off.

    Blocking; used from one worker thread at a time (a lock makes that safe anyway).
    """

    def __init__(self, name: str, host: str, port: int, timeout_s: float) -> None:
        self.name, self.host, self.port, self.timeout_s = name, host, port, timeout_s
        self.backoff = Backoff()
        self.connects = 0                   # successful connections, for tests and logs
        self.last_reply = 0.0               # monotonic time of the last reply
        self._sock: socket.socket | None = None
        self._buf = b""
        self._lock = threading.RLock()
        self._closed = threading.Event()
        # runs on every new connection before anything else is sent (the motion socket's
        # set-up: FRAME, DEFSAFE, ESTOP); an error drops the connection again
        self.on_connect: Callable[[], object] | None = None

    @property
    def where(self) -> str:
        return f"V+ {self.name} server {self.host}:{self.port}"

    @property
    def connected(self) -> bool:
        return self._sock is not None

    # ------------------------------------------------------------------ connection
    def ensure(self, deadline: float, idle_check: bool = True) -> socket.socket:
        """The open socket, connecting (with back-off) until ``deadline`` if needed.
        ``idle_check``: a request socket with something to read between requests is out
        of step (see ``_stale``); not for the notify socket, which talks unasked."""
        last: OSError | None = None
        if idle_check and self._sock is not None and (self._buf or self._stale(self._sock)):
            self._discard()                 # closed while idle: re-connect straight away
        while self._sock is None:
            if self._closed.is_set():
                raise CommsLost(f"{self.where}: client closed")
            now = time.monotonic()
            wait = self.backoff.next_try - now
            if wait > 0:
                if now + wait > deadline:
                    why = f": {last}" if last else " (backing off)"
                    raise CommsLost(f"{self.where}: not connected{why}")
                self._closed.wait(wait)
                continue
            try:
                sock = socket.create_connection((self.host, self.port),
                                                timeout=max(0.05, deadline - now))
            except OSError as e:
                last = e
                self.backoff.failed(time.monotonic())
                if time.monotonic() >= deadline:
                    raise CommsLost(f"{self.where}: cannot connect: {e}") from None
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sock, self._buf = sock, b""
            self.backoff.succeeded()
            self.connects += 1
            if self.on_connect is not None:
                try:
                    self.on_connect()
                except BaseException:
                    self.drop()
                    raise
                if self._sock is None:           # the set-up lost the link: try again
                    continue
        return self._sock

    @staticmethod
    def _stale(sock: socket.socket) -> bool:
        """An idle request socket has nothing to read: if it has, the server closed it
        (EOF) or sent something nobody asked for; either way it is out of step."""
        try:
            sock.setblocking(False)
            sock.recv(1, socket.MSG_PEEK)       # b"" (EOF) or unasked data: stale
            return True
        except BlockingIOError:
            return False                        # nothing to read: fine
        except OSError:
            return True
        finally:
            try:
                sock.setblocking(True)
            except OSError:
                pass

    def _discard(self) -> None:
        sock, self._sock, self._buf = self._sock, None, b""
        if sock is not None:
            sock.close()

    def drop(self) -> None:
        """Close the connection (the next request re-connects after the back-off)."""
        with self._lock:
            sock, self._sock, self._buf = self._sock, None, b""
            if sock is not None:
                self.backoff.dropped(time.monotonic())
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                sock.close()

    def close(self) -> None:
        """Stop for good; a request blocked on the socket fails at once."""
        self._closed.set()
        sock = self._sock
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)     # wakes a worker blocked in recv
            except OSError:
                pass
        self.drop()

    # ------------------------------------------------------------------ lines
    def send(self, line: str, deadline: float) -> None:
        sock = self.ensure(deadline)
        try:
            sock.settimeout(max(0.01, deadline - time.monotonic()))
            sock.sendall(line.encode("ascii"))
        except OSError as e:
            self.drop()
            raise CommsLost(f"{self.where}: send failed: {e}") from None

    def read_line(self, deadline: float, what: str, idle_ok: bool = False,
                  on_timeout: Callable[[], object] | None = None) -> str | None:
        """One line (without its end), waiting until ``deadline``. At the deadline: None if
        ``idle_ok`` (a notify socket may be quiet), else ``on_timeout()`` runs (the robot:
        STOP it), the link is dropped (a reply that comes late would answer the wrong
        request) and ``CommsLost`` raised."""
        sock = self._sock
        if sock is None:
            raise CommsLost(f"{self.where}: not connected")
        while b"\n" not in self._buf:
            if len(self._buf) > protocol.MAX_LINE:
                self.drop()
                raise GarbledReply(f"{self.where}: {what}: line longer than "
                                    f"{protocol.MAX_LINE} characters")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                if idle_ok:
                    return None
                if on_timeout is not None:
                    on_timeout()
                self.drop()
                raise CommsLost(f"{self.where}: no {what} within the time-out")
            try:
                sock.settimeout(remaining)
                chunk = sock.recv(4096)
            except TimeoutError:
                continue
            except OSError as e:
                self.drop()
                raise CommsLost(f"{self.where}: connection lost waiting for {what}: {e}") from None
            if not chunk:
                self.drop()
                raise CommsLost(f"{self.where}: connection closed by the controller "
                                f"waiting for {what}")
            self._buf += chunk
        raw, _, self._buf = self._buf.partition(b"\n")
        try:
            return raw.decode("ascii").rstrip("\r")
        except UnicodeDecodeError:
            self.drop()
            raise GarbledReply(f"{self.where}: {what}: not ASCII: {raw[:60]!r}") from None

    def request(self, socket_name: str, verb: str, *args: object,
                timeout: float | None = None,
                on_timeout: Callable[[], object] | None = None) -> list[str]:
        """Send one request and return the values of its ``OK`` reply (blocking)."""
        cmd: Command = protocol.command(socket_name, verb)
        line = protocol.encode_request(socket_name, verb, *args)
        deadline = time.monotonic() + (self.timeout_s if timeout is None else timeout)
        with self._lock:
            self.send(line, deadline)
            reply = self.read_line(deadline, f"reply to {verb}", on_timeout=on_timeout)
            assert reply is not None
            self.last_reply = time.monotonic()
            try:
                return protocol.parse_reply(reply, cmd)
            except ProtocolError as e:
                self.drop()                 # out of step with the server: start afresh
                raise GarbledReply(f"{self.where}: {e}") from None


class ServerClient:
    """One V+ server: a ``LineSocket`` and the worker thread that owns it."""

    def __init__(self, name: str, host: str, port: int, timeout_s: float) -> None:
        self.name = name
        self.link = LineSocket(name, host, port, timeout_s)
        self.worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"vplus-{name}")
        self.queued = 0                     # requests submitted and not yet ended
        self._queued_lock = threading.Lock()
        self._beat: threading.Thread | None = None

    def keep_alive(self, verb: str, every_s: float) -> None:
        """While the link is up and nothing else is asked for ``every_s``, ask ``verb`` (a
        request with no effect) on the worker: a link that died without a FIN (a pulled
        cable) is found by its time-out within seconds, and the server, which drops a
        client silent for longer (``link.idle`` in vplus/a_server.v2), can tell a quiet
        client from a dead one."""
        def beat() -> None:
            while not self.link._closed.wait(every_s / 4):
                idle = time.monotonic() - self.link.last_reply >= every_s
                if self.link.connected and idle and self.queued == 0:
                    self.submit(verb).add_done_callback(lambda f: f.exception())

        self._beat = threading.Thread(target=beat, name=f"vplus-{self.name}-beat", daemon=True)
        self._beat.start()

    def call(self, verb: str, *args: object, timeout: float | None = None,
             on_timeout: Callable[[], object] | None = None) -> list[str]:
        """Blocking request on the caller's thread (start-up, pollers: never the tick)."""
        return self.link.request(self.name, verb, *args, timeout=timeout, on_timeout=on_timeout)

    def submit(self, verb: str, *args: object, timeout: float | None = None,
               then: Callable[[list[str]], object] | None = None) -> Future:
        """Queue a request on the worker; the future's result is ``then(values)``."""
        def run() -> object:
            try:
                values = self.call(verb, *args, timeout=timeout)
                return then(values) if then is not None else values
            finally:
                self._count(-1)

        self._count(1)
        try:
            return self.worker.submit(run)
        except RuntimeError:                # shut down: closed
            self._count(-1)
            raise

    def _count(self, n: int) -> None:
        with self._queued_lock:
            self.queued += n

    def close(self) -> None:
        self.link.close()
        self.worker.shutdown(wait=False)     # queued requests fail fast: the link is closed
