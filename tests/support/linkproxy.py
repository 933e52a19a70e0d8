"""A link on loopback that dies the way cables die, between a driver and its emulator.

``LinkProxy(port)`` listens on 127.0.0.1 and forwards every connection to the device at
``port``. ``silence()`` stops forwarding in both directions and keeps every socket open: a
pulled cable, no FIN, no RST, the bytes never arrive (they are dropped, as on a cable that
is out); new connections are accepted and hear nothing either. ``refuse()`` closes every
connection and refuses new ones (the device switched off). ``restore()`` forwards again;
connections made while silent stay dead (their handshake with the device never happened),
as a TCP connection through a pulled cable does.
"""

from __future__ import annotations

import select
import socket
import threading


class LinkProxy:
    def __init__(self, port: int) -> None:
        self.upstream = port
        self.mode = "pass"                       # pass | silent | refuse
        self._lock = threading.Lock()
        self._pairs: list[tuple[socket.socket, socket.socket | None]] = []
        self._listen = socket.create_server(("127.0.0.1", 0))
        self.port = self._listen.getsockname()[1]
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True).start()

    # ---------------------------------------------------------------- the cable
    def silence(self) -> None:
        self.mode = "silent"

    def refuse(self) -> None:
        self.mode = "refuse"
        with self._lock:
            pairs, self._pairs = self._pairs, []
        for a, b in pairs:
            for s in (a, b):
                _close(s)

    def restore(self) -> None:
        self.mode = "pass"

    def close(self) -> None:
        self._stop.set()
        _close(self._listen)
        self.refuse()

    # ---------------------------------------------------------------- plumbing
    def _accept(self) -> None:
        while not self._stop.is_set():
            try:
                client, _ = self._listen.accept()
            except OSError:
                return
            if self.mode == "refuse":
                _close(client)
                continue
            device = None
            if self.mode == "pass":
                try:
                    device = socket.create_connection(("127.0.0.1", self.upstream), 5.0)
                except OSError:
                    _close(client)
                    continue
            with self._lock:
                self._pairs.append((client, device))
            threading.Thread(target=self._pump, args=(client, device), daemon=True).start()

    def _pump(self, client: socket.socket, device: socket.socket | None) -> None:
        """Forward both ways. A close at one end reaches the other only while the cable is
        in: through a pulled cable no FIN passes, the far end stays open (half-open)."""
        ends = [client] if device is None else [client, device]
        try:
            while not self._stop.is_set() and ends:
                ready, _, _ = select.select(ends, [], [], 0.05)
                for s in ready:
                    try:
                        data = s.recv(65536)
                    except OSError:
                        data = b""
                    if not data:
                        if self.mode == "pass":
                            raise OSError("closed")
                        ends.remove(s)             # only this end goes
                        _close(s)
                        continue
                    if self.mode != "pass" or device is None:
                        continue                   # the cable is out: the bytes are lost
                    (device if s is client else client).sendall(data)
        except OSError:
            pass
        finally:
            for s in ends:
                _close(s)


def _close(s: socket.socket | None) -> None:
    if s is None:
        return
    try:
        s.close()
    except OSError:
        pass
