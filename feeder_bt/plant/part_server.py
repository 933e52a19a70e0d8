"""``feeder run --part-server [HOST:]PORT``: robots of any brand pull parts from the cell.

The TCP side only: a thread accepts connections (one thread per robot) and turns each
request line into a ``Pending`` in the desk's inbox; the tick thread answers it
(``ServeRobots`` while feeding, ``Desk.serve_idle`` otherwise) and the connection's thread
writes the answer back. The cell never waits on a robot, and a robot that goes away
leaves only records that time out (behaviours/serve.py).

``install(cell, desk)`` makes the cell build the part server's trees (trees/serve.py)
instead of the retrieve tree each time it starts.
"""

from __future__ import annotations

import itertools
import select
import socket
import socketserver
import threading
from typing import Any

from ..behaviours.serve import Desk, Pending
from ..cell import Cell, CellState
from ..part_protocol import MAX_LINE
from ..trees.serve import build_serving, build_serving_cleanup, build_serving_setup

DEFAULT_PORT = 7600
POLL_S = 0.2               # how often a waiting connection thread checks for shutdown


def install(cell: Cell, desk: Desk) -> None:
    """From now on the cell feeds with the part server's trees: at each start the set-up,
    feeding and clean-up trees are swapped for the ones without robot steps.

    (A small hook in ``Cell`` — a tree-builder attribute — would make this a plain
    assignment; until then a state listener swaps the trees as the cell switches.)"""

    def swap(old: CellState, new: CellState) -> None:
        ctx = cell.ctx
        if ctx is None:
            return
        if new is CellState.STARTING:
            cell.feeding = build_serving(ctx, desk)
            cell.root = build_serving_setup(ctx)
        elif new in (CellState.STOPPING, CellState.FAULTING) and cell.root is not None:
            cell.root = build_serving_cleanup(ctx)

    cell.listeners.append(swap)
    desk.status = lambda: _cell_status(cell)


def _cell_status(cell: Cell) -> dict[str, Any]:
    out: dict[str, Any] = {"state": cell.state.value,
                           "scenario": cell.scenario.name if cell.scenario else "-"}
    if cell.fault_reason:
        out["fault"] = cell.fault_reason
    return out


class _Handler(socketserver.StreamRequestHandler):
    server: _Server

    def setup(self) -> None:
        super().setup()
        self.conn = f"robot-{next(self.server.ids)}@{self.client_address[0]}:" \
                    f"{self.client_address[1]}"
        self.server.connected(self.conn, +1)

    def handle(self) -> None:
        while not self.server.closing.is_set():
            try:
                raw = self.rfile.readline(MAX_LINE + 2)
            except (OSError, ValueError):
                return
            if not raw:
                return                                  # the robot closed the connection
            if not raw.endswith(b"\n") and len(raw) > MAX_LINE:
                self._write(f"ERR line longer than {MAX_LINE} characters: closing")
                return
            line = raw.decode("ascii", errors="replace").rstrip("\r\n")
            done = threading.Event()
            box: list[str] = []

            def answer(text: str, box: list[str] = box, done: threading.Event = done) -> None:
                box.append(text)
                done.set()

            item = Pending(self.conn, line, answer)
            self.server.desk.inbox.put(item)
            while not done.wait(POLL_S):
                if self.server.closing.is_set():
                    item.cancelled = True
                    self._write("ERR the cell controller is shutting down")
                    return
                if self._hung_up():      # gone while its PART waited: hand it nothing
                    item.cancelled = True
                    return
            if not self._write(box[0]) or box[0] == "OK BYE":
                return

    def _hung_up(self) -> bool:
        try:
            ready, _, _ = select.select([self.connection], [], [], 0)
            return bool(ready) and self.connection.recv(1, socket.MSG_PEEK) == b""
        except OSError:
            return True

    def _write(self, text: str) -> bool:
        try:
            self.wfile.write(text.encode("ascii", errors="replace") + b"\n")
            self.wfile.flush()
            return True
        except OSError:
            return False

    def finish(self) -> None:
        try:
            super().finish()
        except OSError:
            pass
        self.server.connected(self.conn, -1)


class _Server(socketserver.ThreadingTCPServer):
    daemon_threads = True
    allow_reuse_address = True

    def __init__(self, address: tuple[str, int], desk: Desk) -> None:
        self.desk = desk
        self.ids = itertools.count(1)
        self.closing = threading.Event()
        self.lock = threading.Lock()
        self.robots: set[str] = set()
        self.total_connections = 0
        family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.address_family = family
        super().__init__(address, _Handler)

    def connected(self, conn: str, delta: int) -> None:
        with self.lock:
            if delta > 0:
                self.robots.add(conn)
                self.total_connections += 1
            else:
                self.robots.discard(conn)


class PartServer:
    """The listening socket and its thread; ``start()`` returns ``host:port``."""

    def __init__(self, desk: Desk, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> None:
        self.desk = desk
        self.server = _Server((host, port), desk)
        desk.alive = lambda conn: conn in self.server.robots
        self.thread = threading.Thread(target=self.server.serve_forever,
                                       kwargs={"poll_interval": POLL_S},
                                       name="part-server", daemon=True)

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.server.server_address[:2]
        return str(host), int(port)

    def start(self) -> str:
        self.thread.start()
        host, port = self.address
        return f"{host}:{port}"

    def close(self) -> None:
        """Stop accepting; waiting robots are told the controller is shutting down."""
        self.server.closing.set()
        self.server.shutdown()
        self.server.server_close()
        self.thread.join(timeout=5.0)

    def report(self) -> dict[str, Any]:
        return {"address": "{}:{}".format(*self.address),
                "connections": self.server.total_connections, **self.desk.report()}
