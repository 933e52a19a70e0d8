"""The I/O side of the V+ emulator (``adept.py``): the I/O server and io_notify, and the
helpers the servers share. A mixin of ``AdeptEmulator``: it uses its ``plant``, ``soft``
signals and ``_stop`` flag."""

from __future__ import annotations

import socket
import threading

from ..hal.adept import protocol as P
from .plant import Plant

NOTIFY_PERIOD_S = 0.01       # io_notify polls the inputs every major cycle (16 ms on V+)


def _cut(conn: socket.socket) -> None:
    """The cable is pulled: both directions go (the client sees the connection drop)."""
    try:
        conn.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass


class BadArgument(Exception):
    """A request argument the V+ program would refuse (reply ERR -9002)."""


def _err(code: int) -> str:
    return f"ERR {code} {P.error_text(code)}"


def _num(v: float) -> str:
    return f"{v:.3f}"


def _as_int(v: float) -> int:
    if v != int(v):
        raise BadArgument(f"{v} is not an integer")
    return int(v)


def _as_flag(v: float) -> bool:
    if v not in (0.0, 1.0):
        raise BadArgument(f"{v} is not 0 or 1")
    return v == 1.0


class IoServers:
    """io_server (SIG, SET) and io_notify (IN lines) over the plant's signals."""

    plant: Plant
    soft: dict[int, bool]
    _stop: threading.Event

    # ------------------------------------------------------------------ I/O server
    def _signal_name(self, signal: int) -> str | None:
        """The cell's name of a V+ signal on this controller (None: nothing wired)."""
        bit, is_input = P.bit_of(signal)
        for name, sig in self.plant.cell.io.items():
            if sig.controller != "adept" or (sig.dir == "in") != is_input:
                continue
            if sig.bit in (bit, signal):
                return name
        return None

    @staticmethod
    def _check_signal(signal: int) -> None:
        if not (1 <= signal < P.INPUT_BASE or P.INPUT_BASE < signal < P.SOFT_BASE
                or P.SOFT_BASE < signal < P.SOFT_BASE + 1000):
            raise BadArgument(f"no V+ signal {signal}")

    def _read_signal(self, signal: int) -> bool:
        if signal > P.SOFT_BASE:
            return self.soft.get(signal, False)
        name = self._signal_name(signal)
        return self.plant.signal(name) if name is not None else False

    def _sig(self, s: float) -> str:
        signal = _as_int(s)
        self._check_signal(signal)
        return f"OK {int(self._read_signal(signal))}"

    def _set(self, s: float, v: float) -> str:
        signal, value = _as_int(s), _as_flag(v)
        self._check_signal(signal)
        if P.INPUT_BASE < signal < P.SOFT_BASE:
            raise BadArgument("an input cannot be set")
        if signal > P.SOFT_BASE:
            self.soft[signal] = value
        else:
            name = self._signal_name(signal)
            if name is not None:
                self.plant.set_signal(name, value)
        return "OK"

    # ------------------------------------------------------------------ io_notify
    def _inputs(self) -> list[tuple[int, str]]:
        return [(P.signal_of(sig.bit, True), name) for name, sig in self.plant.cell.io.items()
                if sig.controller == "adept" and sig.dir == "in"]

    def _notify_session(self, conn: socket.socket) -> None:
        """io_notify: on connection send every input's state, then a line per change."""
        inputs = self._inputs()
        last: dict[int, bool] = {}
        for signal, name in inputs:
            last[signal] = self.plant.signal(name)
            conn.sendall(f"IN {signal} {int(last[signal])}\r\n".encode("ascii"))
        conn.settimeout(NOTIFY_PERIOD_S)
        while not self._stop.is_set():
            try:
                if not conn.recv(4096):
                    return                      # the PC closed the socket: reset
            except TimeoutError:
                pass                            # nothing from the PC: the usual case
            for signal, name in inputs:
                value = self.plant.signal(name)
                if value != last[signal]:
                    last[signal] = value
                    conn.sendall(f"IN {signal} {int(value)}\r\n".encode("ascii"))
