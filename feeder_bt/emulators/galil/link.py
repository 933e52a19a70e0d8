"""The Galil emulator's links: one client connection (a TCP socket, holding an Ethernet
handle, or the master side of a pty, the serial port) and the command-line state of each
(partial command, echo, ``DL`` mode)."""

from __future__ import annotations

import os
import select
import socket
import threading
import time
import tty
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from feeder_bt.emulators.galil.emulator import GalilEmulator

POLL_S = 0.05                  # how often idle server threads look at the stop flag


class Link:
    """One client connection (TCP socket or pty master): bytes in, bytes out."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.closed = threading.Event()
        self._wlock = threading.Lock()
        self.handle: str | None = None         # Ethernet handle letter (TCP only)
        self.client_closed = False             # the client closed it (the handle is free)

    def write(self, data: bytes) -> None:
        if self.closed.is_set():
            return
        with self._wlock:
            try:
                self._write(data)
            except OSError:
                self.close()

    def _write(self, data: bytes) -> None:
        raise NotImplementedError

    def read(self) -> bytes:
        """Some bytes (b'' on a quiet period); raises OSError when the link is gone."""
        raise NotImplementedError

    def close(self) -> None:
        self.closed.set()


class TcpLink(Link):
    def __init__(self, sock: socket.socket, name: str) -> None:
        super().__init__(name)
        self.sock = sock
        sock.settimeout(2.0)                  # a client that stops reading is dropped
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _write(self, data: bytes) -> None:
        self.sock.sendall(data)

    def read(self) -> bytes:
        try:
            ready, _, _ = select.select([self.sock], [], [], POLL_S)
        except ValueError:                     # closed from this side meanwhile
            raise OSError("link closed") from None
        if not ready:
            return b""
        data = self.sock.recv(4096)
        if not data:
            if not self.closed.is_set():       # not our own shutdown: the client's FIN
                self.client_closed = True
            raise OSError("client closed the connection")
        return data

    def close(self) -> None:
        if not self.closed.is_set():
            super().close()
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            self.sock.close()


class PtyLink(Link):
    """The master side of a pseudo-terminal; the driver opens the slave as a serial port."""

    def __init__(self) -> None:
        super().__init__("pty")
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)                # no echo, no CR/LF translation
        os.set_blocking(self.master, False)   # nobody reading: output is lost, not stuck
        self.path = os.ttyname(self.slave)

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        end = time.monotonic() + 0.5
        while view and time.monotonic() < end:
            try:
                view = view[os.write(self.master, view):]
            except BlockingIOError:           # the slave's buffer is full: wait a little
                time.sleep(0.005)

    def read(self) -> bytes:
        ready, _, _ = select.select([self.master], [], [], POLL_S)
        if not ready:
            return b""
        try:
            return os.read(self.master, 4096)
        except OSError:                       # EIO while the slave is closed: keep serving
            time.sleep(0.05)
            return b""

    def close(self) -> None:
        if not self.closed.is_set():
            super().close()
            for fd in (self.master, self.slave):
                try:
                    os.close(fd)
                except OSError:
                    pass


class Session:
    """Command-line state of one link: the partial command, DL mode."""

    def __init__(self, emu: GalilEmulator, link: Link) -> None:
        self.emu, self.link = emu, link
        self.buf: list[str] = []
        self.quoted = False
        self.dl: list[str] | None = None       # program text while downloading

    def feed(self, data: bytes) -> None:
        for byte in data:
            if self.link.closed.is_set():
                return
            ch = chr(byte & 0x7F)
            if self.emu.echo and isinstance(self.link, PtyLink):
                self.link.write(bytes([byte & 0x7F]))     # a serial port echoes until EO 0
            if self.dl is not None:
                if ch == "\\":
                    text, self.dl = "".join(self.dl), None
                    self.emu._finish_download(self.link, text)
                else:
                    self.dl.append(ch)
                continue
            if ch == '"':
                self.quoted = not self.quoted
            if ch == "\r" or (ch == ";" and not self.quoted):
                cmd, self.buf, self.quoted = "".join(self.buf), [], False
                if self.emu._handle(self.link, cmd):
                    self.dl = []
            elif ch != "\n":
                self.buf.append(ch)
