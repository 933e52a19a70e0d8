"""A link on loopback that dies the way cables die, between a driver and its device.

``LinkProxy(port)`` listens on 127.0.0.1 and forwards every connection to the device at
``port`` (an emulator, or a real controller on a bench). Commissioning and the link
matrix (``benchmarks/link_matrix.py``) put it between the real drivers and the emulators
to show that every way a link dies ends in a recovery or a FAULT naming the link:

``silence()``
    a pulled cable: no FIN, no RST, the bytes are lost both ways; new connections are
    accepted and hear nothing. ``restore()`` plugs it back: a TCP connection survives a
    short pull, so the old connections carry bytes again.
``half_open()``
    a pulled cable, then the device rebooted (or its idle time-out dropped the peer): as
    silence, but the connections open now stay dead after ``restore()``. The device end is
    left open, as a controller that has not noticed its client is gone keeps it; the
    driver must find the dead link by its own keep-alive and the device must take the new
    client.
``refuse()``
    the device switched off: every connection is closed and new ones refused.
``drip(every_s)``
    a congested or failing line: bytes still arrive, both ways, one every ``every_s``;
    ``restore()`` delivers what is queued, in order.
``flood()``
    a line full of noise: the device's replies are lost and the driver receives an endless
    stream of bytes with no line end; what the driver sends is lost.
``garbage()``
    a corrupting line: each chunk the device sends arrives as the same number of random
    bytes, its line ends kept (so the driver reads whole lines of garbage).

Nothing here knows a protocol: the deaths are of the cable, not of a controller.
"""

from __future__ import annotations

import random
import select
import socket
import threading
import time

MODES = ("pass", "silent", "half_open", "refuse", "drip", "flood", "garbage")


class LinkProxy:
    def __init__(self, port: int, host: str = "127.0.0.1", seed: int = 0) -> None:
        self.upstream = (host, port)
        self.mode = "pass"
        self.drip_s = 0.5
        self._rng = random.Random(seed)
        self._lock = threading.Lock()
        self._pairs: list[_Pair] = []
        self._listen = socket.create_server(("127.0.0.1", 0))
        self.port = self._listen.getsockname()[1]
        self._stop = threading.Event()
        threading.Thread(target=self._accept, daemon=True, name="linkproxy").start()

    # ---------------------------------------------------------------- the cable
    def silence(self) -> None:
        self.mode = "silent"

    def half_open(self) -> None:
        with self._lock:
            for pair in self._pairs:
                pair.dead = True
        self.mode = "silent"

    def refuse(self) -> None:
        self.mode = "refuse"
        with self._lock:
            pairs, self._pairs = self._pairs, []
        for pair in pairs:
            pair.close()

    def drip(self, every_s: float = 0.5) -> None:
        self.drip_s = every_s
        self.mode = "drip"

    def flood(self) -> None:
        self.mode = "flood"

    def garbage(self) -> None:
        self.mode = "garbage"

    def cut(self, how: str) -> None:
        """Start one death by its name (``MODES`` less ``pass``; ``half-open`` too)."""
        how = how.replace("-", "_")
        if how in ("silence", "silent"):
            self.silence()
        elif how in ("half_open", "refuse", "drip", "flood", "garbage"):
            getattr(self, how)()
        else:
            raise ValueError(f"unknown link death {how!r}; one of: silence, half_open, "
                             "refuse, drip, flood, garbage")

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
            if self.mode in ("pass", "drip", "garbage"):
                try:
                    device = socket.create_connection(self.upstream, 5.0)
                except OSError:
                    _close(client)
                    continue
            pair = _Pair(client, device)
            with self._lock:
                self._pairs.append(pair)
            threading.Thread(target=self._pump, args=(pair,), daemon=True,
                             name="linkproxy-pump").start()

    def _pump(self, pair: _Pair) -> None:
        """Forward both ways by the mode of the moment. A close at one end reaches the
        other only while the cable is in: through a pulled cable no FIN passes, the far end
        stays open (half-open)."""
        client, device = pair.client, pair.device
        ends = [client] if device is None else [client, device]
        try:
            while not self._stop.is_set() and ends:
                mode = "silent" if pair.dead or device is None else self.mode
                if mode == "flood" and select.select([], [client], [], 0)[1]:
                    client.send(bytes(self._rng.randrange(33, 127) for _ in range(4096)))
                if mode != "drip" and pair.queue:
                    pair.flush()                     # the line cleared: what queued arrives
                elif mode == "drip":
                    pair.drip_one(self.drip_s)
                ready, _, _ = select.select(ends, [], [], 0.02 if mode == "flood" else 0.05)
                # the mode of the moment the bytes came, not of before the wait: a cut made
                # while waiting must drop them
                mode = "silent" if pair.dead or device is None else self.mode
                for s in ready:
                    try:
                        data = s.recv(65536)
                    except OSError:
                        data = b""
                    if not data:
                        if mode == "pass":
                            raise OSError("closed")
                        ends.remove(s)               # only this end goes
                        _close(s)
                        continue
                    to = device if s is client else client
                    if mode in ("silent", "flood"):
                        continue                     # the cable is out: the bytes are lost
                    if mode == "drip":
                        pair.queue.extend((to, bytes([b])) for b in data)
                    elif mode == "garbage" and s is device:
                        to.sendall(self._garble(data))
                    else:
                        to.sendall(data)
        except (OSError, ValueError):            # ValueError: an end closed by refuse()
            pass
        finally:
            for s in ends:
                _close(s)

    def _garble(self, data: bytes) -> bytes:
        return bytes(b if b in (10, 13) else self._rng.randrange(0, 256) for b in data)


class _Pair:
    """One connection through the proxy: the driver's end and the device's."""

    def __init__(self, client: socket.socket, device: socket.socket | None) -> None:
        self.client, self.device = client, device
        self.dead = False                            # half-open: silent for good
        self.queue: list[tuple[socket.socket, bytes]] = []
        self._next_drip = 0.0

    def drip_one(self, every_s: float) -> None:
        now = time.monotonic()
        if self.queue and now >= self._next_drip:
            to, byte = self.queue.pop(0)
            _send(to, byte)
            self._next_drip = now + every_s

    def flush(self) -> None:
        queue, self.queue = self.queue, []
        for to, byte in queue:
            _send(to, byte)

    def close(self) -> None:
        _close(self.client)
        _close(self.device)


def _send(s: socket.socket, data: bytes) -> None:
    try:
        s.sendall(data)
    except OSError:
        pass


def _close(s: socket.socket | None) -> None:
    if s is None:
        return
    try:
        s.close()
    except OSError:
        pass
