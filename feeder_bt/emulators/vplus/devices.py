"""V+ TCP server sockets (ATTACH, FOPEN, READ, WRITE, FCMND, FCLOSE, DETACH, IOSTAT) on real
loopback listeners.

What the programs rely on (thesis 7.3.1 and Figure 7-1; V+ TCP/IP User's Guide): a server
socket opened with ``/LOCAL_PORT n /CLIENTS 1``; ``READ (lun, handle, mode) $line``
returns, through ``IOSTAT(lun)``: 100 when a client connected (``handle`` is its
handle), 1 with a line, 101 when the client closed its end, -526 when a no-wait READ
(mode 1) found nothing; any other negative status is a broken link (here -527, NOT
CONFIRMED: the number a real controller gives). ``WRITE`` appends CR LF; a write to a
broken link sets a negative IOSTAT (NOT CONFIRMED: it might raise a program error, which
the traps would note). ``FCMND (lun, 640) handle`` drops one client and keeps listening.

The listeners are bound when the emulator starts (the V+ port numbers map to the
emulator's ports), so they outlive FCLOSE/FOPEN as the controller's would.
The emulator's fault plan acts here, on the request lines (``reject``, ``drop``,
``drop_during``, ``drop_after``, ``stall``; ``servo_timeout`` arms the arm).
"""

from __future__ import annotations

import re
import select
import socket
import threading
import time
from typing import TYPE_CHECKING

from feeder_bt.emulators.vplus.task import Killed, VError
from feeder_bt.hal.adept import protocol as P

if TYPE_CHECKING:
    from feeder_bt.emulators.vplus.runtime import Runtime

ST_DATA, ST_CONNECT, ST_CLOSED, ST_NODATA, ST_BROKEN = 1, 100, 101, -526, -527
MOTIONS = ("PICK", "PLACE", "MOVE", "SAFE")
_PORT = re.compile(r"/LOCAL_PORT\s+(\d+)", re.IGNORECASE)


def cut(conn: socket.socket) -> None:
    """The cable is pulled: both directions go."""
    try:
        conn.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass


class TcpLun:
    """One logical unit ATTACHed to the TCP device: a server socket and its one client."""

    def __init__(self, rt: Runtime, lun: int) -> None:
        self.rt, self.lun = rt, lun
        self.server = ""
        self.listener: socket.socket | None = None
        self.client: socket.socket | None = None
        self.handle = 0
        self.buf = b""
        self.status = 0
        self.drop_reply = False
        self.stall_s = 0.0
        self.stall_release: threading.Event | None = None

    def fopen(self, spec: str) -> None:
        m = _PORT.search(spec)
        if not m or int(m.group(1)) not in self.rt.listeners:
            raise VError(-522, f"no listener for {spec!r}")
        self.server, self.listener = self.rt.listeners[int(m.group(1))]
        self.status = 0

    def close_client(self) -> None:
        client, self.client, self.buf = self.client, None, b""
        if client is not None:
            self.rt.forget(client)
            cut(client)
            client.close()

    # ------------------------------------------------------------ READ
    def read(self, mode: int) -> tuple[int, int, str]:
        """(status, handle, line); mode 0 waits, 1 does not."""
        while True:
            if self.rt.killed:
                raise Killed()
            if self.listener is None:
                self.status = ST_BROKEN
                return self.status, self.handle, ""
            if self.client is None:
                ready, _, _ = select.select([self.listener], [], [], 0 if mode else 0.05)
                if ready:
                    try:
                        conn, _ = self.listener.accept()
                    except OSError:
                        continue
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    self.client, self.buf = conn, b""
                    self.handle += 1
                    self.rt.accepted(self.server, conn)
                    self.status = ST_CONNECT
                    return self.status, self.handle, ""
            else:
                line = self._line(mode)
                if line is not None:
                    return line
            if mode:
                self.status = ST_NODATA
                return self.status, self.handle, ""

    def _line(self, mode: int) -> tuple[int, int, str] | None:
        while b"\n" not in self.buf:
            if len(self.buf) > P.MAX_LINE:         # READ buffer overflow: refuse, resync
                self.buf = b""
                self._send_raw(f"ERR {P.CODE_BAD_ARGUMENT} {P.error_text(P.CODE_BAD_ARGUMENT)}")
            client = self.client
            if client is None:
                self.status = ST_CLOSED
                return self.status, self.handle, ""
            try:
                ready, _, _ = select.select([client], [], [], 0 if mode else 0.05)
                if not ready:
                    return None
                chunk = client.recv(4096)
            except (OSError, ValueError):
                self.status = ST_BROKEN
                return self.status, self.handle, ""
            if not chunk:
                self.status = ST_CLOSED
                return self.status, self.handle, ""
            self.buf += chunk
        raw, _, self.buf = self.buf.partition(b"\n")
        text = raw.decode("ascii", "replace")
        if self.server in ("motion", "position", "io") and text.strip():
            verdict = self._fault(text)
            if verdict == "skip":
                return None
            if verdict == "drop":
                self.status = ST_CLOSED
                return self.status, self.handle, ""
        self.status = ST_DATA                  # READ ends at the LF; a CR stays in the line
        return self.status, self.handle, text

    def _fault(self, text: str) -> str | None:
        """The fault plan's verdict on a request line (None: deliver it)."""
        line = text.strip()
        self.rt.requests.append((self.server, line.rstrip("\r")))
        faults = self.rt.faults
        rule = faults.check("adept", line) if faults is not None else None
        if rule is None:
            return None
        if rule.kind == "reject":
            self._send_raw(f"ERR {P.CODE_REJECTED} {P.error_text(P.CODE_REJECTED)}")
            return "skip"
        if rule.kind == "drop":
            self.close_client()
            return "drop"
        if rule.kind == "drop_during":
            client = self.client
            timer = threading.Timer(rule.after_s, cut, (client,))
            timer.daemon = True
            timer.start()
        elif rule.kind == "drop_after":
            self.drop_reply = True
        elif rule.kind == "stall":
            self.stall_s, self.stall_release = rule.stall_s, rule.released
        elif rule.kind == "servo_timeout" and line.split()[0] in MOTIONS:
            self.rt.arm.fault_armed = True
        return None

    # ------------------------------------------------------------ WRITE
    def _send_raw(self, text: str) -> bool:
        if self.client is None:
            return False
        try:
            self.client.sendall((text + "\r\n").encode("ascii", "replace"))
            return True
        except OSError:
            return False

    def _hold(self, stall_s: float, release: threading.Event | None) -> None:
        """A ``stall``: the reply waits ``stall_s``, or until the rule is released (the
        emulator's stop still ends it: ``rt.sleep`` raises ``Killed``)."""
        end = time.monotonic() + stall_s
        while (left := end - time.monotonic()) > 0:
            if release is not None and release.is_set():
                return
            self.rt.sleep(min(left, 0.02))

    def write(self, handle: int, text: str) -> None:
        if self.drop_reply:
            self.drop_reply = False
            if self.client is not None:
                cut(self.client)
            self.status = ST_BROKEN
            return
        if self.stall_s:
            stall, self.stall_s = self.stall_s, 0.0
            self._hold(stall, self.stall_release)
        self.status = 0 if self._send_raw(text) else ST_BROKEN
