"""``feeder run --part-server [HOST:]PORT``: robots of any brand pull parts from the cell.

The TCP side only: one thread runs an asyncio loop that holds every connection (no
thread per robot) and turns each request line into a ``Pending`` in the desk's inbox; the
tick thread answers it (``ServeRobots`` while feeding, ``Desk.serve_idle`` otherwise) and
the answer is handed back to the loop, which writes it. The cell never waits on a robot,
and a robot that goes away leaves only records that time out (behaviours/serve.py).

Nobody on the network can starve it: connections pass a ``control.conns.ConnGate`` (one
that has said nothing waits in its lobby, where only another silent one can take its
place; then a cap per address and in all; over either, the oldest connection that has not
said who it is makes room; a robot that proved who it is moves into the gate's reserve, outside the
caps, and when every capped connection is busy a newcomer is let in on trial and closed
unless its first line proves it a robot), a connection must send its first line within ``header_s`` and is closed
after ``idle_s`` of silence with nothing asked; the backlog is the system's ceiling.
Robots must be trusted (``robots.RobotTrust``): a robot named in the robots file proves
who it is by challenge and response (``HELLO NAME`` → ``OK CHALLENGE nonce``, a fresh nonce
per connection; ``PROOF hmac``), or by its address; the plain ``HELLO NAME SECRET`` only
where the file allows it for that robot. Without a robots file only loopback peers are
served. A robot cut off by the desk (parts taken and never reported) has its
connections closed and its ``HELLO`` refused until the cut-off ends.

``install(cell, desk)`` makes the cell build the part server's trees (trees/serve.py)
instead of the retrieve tree each time it starts.
"""

from __future__ import annotations

import asyncio
import itertools
import secrets
import socket
import threading
from concurrent.futures import Future
from typing import Any

from feeder_bt.behaviours.desk import Desk, Pending
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.conns import ConnGate, ConnLimits, backlog, peer_ip
from feeder_bt.core.part_protocol import MAX_LINE
from feeder_bt.plant.robots import RobotTrust
from feeder_bt.trees.desk import build_serving, build_serving_cleanup, build_serving_setup

DEFAULT_PORT = 7600
SWEEP_S = 1.0              # how often idle connections are looked for
IN_FLIGHT = 8              # requests a connection may have waiting; then it is not read
#: a lobby of 256 for connections that have said nothing yet, outside the caps, so silent
#: ones never displace a robot that has sent its first line, nor (being fewer than 256 and
#: more than one accept burst) one about to: at most 256 + 256 + 32 = 544 connections open
LIMITS = ConnLimits(total=256, per_address=16, header_s=10.0, idle_s=120.0, reserve=32,
                    lobby=256)
FREE = ("HELP", "QUIT")    # what a robot may ask before it has said who it is
AUTH = ("HELLO", "PROOF")  # how it says who it is
NONCE_BYTES = 16           # a challenge: 128 random bits, new for every HELLO NAME


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


class _Conn(asyncio.Protocol):
    """One robot connection on the server's loop."""

    def __init__(self, srv: _Server) -> None:
        self.srv = srv
        self.transport: asyncio.Transport | None = None
        self.name = ""                     # the desk's name for this connection
        self.robot: str | None = None      # who it proved to be (None: not yet)
        self.buf = b""
        self.waiting: list[list[Any]] = []  # [Pending, reply] in order, not yet written
        self.seen = 0.0
        self.lines = 0
        self.closing = False
        self.paused = False
        self.challenge: tuple[str, str] | None = None   # (name, nonce) awaiting PROOF

    # ------------------------------------------------------------------ life
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        srv = self.srv
        if not srv.gate.admit(transport, self._busy):
            return
        self.transport = transport  # type: ignore[assignment]
        ip = peer_ip(transport)
        peer = transport.get_extra_info("peername") or ("?", 0)
        self.ip, self.port = ip, peer[1]
        self.seen = srv.loop.time()
        self.name = f"robot-{next(srv.ids)}@{ip}:{self.port}"
        if srv.trust.robots:
            r = srv.trust.by_address(ip)
            if r is not None:
                self._become(r.name)
                srv.gate.vouch(transport, lambda: True)
        elif _loopback(ip):
            self.robot = ""                # anonymous: this machine, this connection
        srv.conns.add(self)
        srv.connected(self.name, +1)

    def _become(self, robot: str) -> None:
        old = self.name
        self.robot = robot
        self.name = f"{robot}#{next(self.srv.ids)}@{self.ip}:{self.port}"
        if old in self.srv.robots:
            self.srv.robots.discard(old)
            self.srv.robots.add(self.name)

    def _busy(self) -> bool:
        return bool(self.robot) or bool(self.waiting)

    def connection_lost(self, exc: Exception | None) -> None:
        if self.transport is None:
            return                         # refused at the door
        self.srv.gate.release(self.transport)
        self.srv.conns.discard(self)
        for slot in self.waiting:          # gone while its PART waited: hand it nothing
            if slot[0] is not None:
                slot[0].cancelled = True
        self.waiting.clear()
        self.srv.connected(self.name, -1)

    def close(self, last: str | None = None) -> None:
        if self.transport is None or self.closing:
            return
        self.closing = True
        if last is not None:
            self.transport.write(last.encode("ascii", "replace") + b"\n")
        self.transport.close()

    # ------------------------------------------------------------------ lines
    def data_received(self, data: bytes) -> None:
        if self.closing:
            return
        self.seen = self.srv.loop.time()
        if self.transport is not None and not self.srv.gate.heard(self.transport):
            return                         # refused as it left the lobby: aborted
        self.buf += data
        while b"\n" in self.buf and not self.closing:
            raw, _, self.buf = self.buf.partition(b"\n")
            if len(raw) > MAX_LINE + 1:
                self.close(f"ERR line longer than {MAX_LINE} characters: closing")
                return
            self._line(raw.decode("ascii", errors="replace").rstrip("\r"))
        if len(self.buf) > MAX_LINE + 1:
            self.close(f"ERR line longer than {MAX_LINE} characters: closing")

    def _line(self, line: str) -> None:
        self.lines += 1
        words = line.split()
        cmd = words[0].upper() if words else ""
        on_trial = self.transport is not None and self.srv.gate.on_trial(self.transport)
        if on_trial and cmd not in AUTH:
            self.srv.gate.note("closed: a connection on trial that did not say HELLO")
            self.close("ERR the part server is busy: say HELLO first, or try again")
            return
        if cmd in AUTH:
            reply = self._hello(words) if cmd == "HELLO" else self._proof(words)
            self._reply_now(reply)
            if on_trial and reply.startswith("ERR"):
                self.srv.gate.note("closed: a connection on trial that did not prove "
                                   "who it is")
                self.close()
            return
        if self.robot is None and cmd not in FREE:
            self.srv.gate.note("refused: a request before HELLO")
            self._reply_now("ERR who are you? Send HELLO NAME first and answer its "
                            "challenge with PROOF (a robot named in the part server's "
                            "robots file)")
            return
        if self.robot and self.srv.cut_off(self.robot):
            self.close(f"ERR robot {self.robot} is cut off: parts handed to it were never "
                       "reported")
            return
        slot: list[Any] = [None, None]           # [Pending, its reply when it comes]

        def answer(text: str, slot: list[Any] = slot) -> None:   # tick thread
            try:
                self.srv.loop.call_soon_threadsafe(self._answered, slot, text)
            except RuntimeError:                 # the loop has ended
                pass

        slot[0] = Pending(self.name, line, answer)
        self.waiting.append(slot)
        self.srv.desk.inbox.put(slot[0])
        if len(self.waiting) >= IN_FLIGHT and not self.paused and self.transport:
            self.paused = True
            self.transport.pause_reading()

    def _hello(self, words: list[str]) -> str:
        """``HELLO NAME``: a challenge, a fresh nonce for this connection, whoever asks
        (an unknown name gets one too: the answer tells nothing). ``HELLO NAME SECRET``:
        the plain form, for a robot the robots file lets use it."""
        srv = self.srv
        if len(words) not in (2, 3):
            return "ERR usage: HELLO NAME (then PROOF HMAC of the challenge)"
        if self.robot:
            return f"ERR this connection is robot {self.robot} already"
        if len(words) == 2:
            self.challenge = (words[1], secrets.token_hex(NONCE_BYTES))
            return f"OK CHALLENGE {self.challenge[1]}"
        self.challenge = None
        r = srv.trust.hello(words[1], words[2], self.ip)
        if r is None:
            return self._refused("ERR HELLO: unknown robot, wrong secret or address, or "
                                 "a plain secret this robot may not send (HELLO NAME, "
                                 "then PROOF)")
        return self._proved(r)

    def _proof(self, words: list[str]) -> str:
        """``PROOF hex``: the answer to this connection's challenge; one try per nonce."""
        if self.robot:
            return f"ERR this connection is robot {self.robot} already"
        challenge, self.challenge = self.challenge, None
        if challenge is None:
            return self._refused("ERR PROOF: no challenge: send HELLO NAME first")
        if len(words) != 2:
            return self._refused("ERR usage: PROOF HMAC (64 hex digits)")
        r = self.srv.trust.answer(challenge[0], challenge[1], words[1], self.ip)
        if r is None:
            return self._refused("ERR HELLO: unknown robot, wrong proof or address")
        return self._proved(r)

    def _refused(self, reply: str) -> str:
        self.srv.gate.note("refused: a wrong HELLO")
        self.srv.refused_hellos += 1
        return reply

    def _proved(self, r: Any) -> str:
        srv = self.srv
        if srv.cut_off(r.name):
            return f"ERR robot {r.name} is cut off: parts handed to it were never reported"
        self._become(r.name)
        if self.transport is not None:
            srv.gate.vouch(self.transport, lambda: True)   # a robot's: the reserve's
        return f"OK HELLO {r.name}"

    def _reply_now(self, text: str) -> None:
        if self.waiting:                   # in order, behind what the desk still answers
            slot: list[Any] = [None, None]
            self.waiting.append(slot)
            self._answered(slot, text)
            return
        self._write(text)

    def _answered(self, slot: list[Any], text: str) -> None:
        """On the loop: an answer came; write every answer that is next in order."""
        slot[1] = text
        while self.waiting and self.waiting[0][1] is not None:
            reply = self.waiting.pop(0)[1]
            self._write(reply)
            if reply == "OK BYE":
                self.close()
                return
        if self.paused and len(self.waiting) < IN_FLIGHT and self.transport:
            self.paused = False
            self.transport.resume_reading()

    def _write(self, text: str) -> None:
        if self.transport is not None and not self.closing:
            self.transport.write(text.encode("ascii", errors="replace") + b"\n")
            self.seen = self.srv.loop.time()


def _loopback(ip: str) -> bool:
    import ipaddress
    try:
        return ipaddress.ip_address(ip).is_loopback
    except ValueError:
        return False


class _Server:
    """The loop, its listening socket and its connections (what ``PartServer`` runs)."""

    def __init__(self, address: tuple[str, int], desk: Desk, trust: RobotTrust,
                 limits: ConnLimits) -> None:
        self.desk, self.trust, self.limits = desk, trust, limits
        self.ids = itertools.count(1)
        self.closing = threading.Event()
        self.lock = threading.Lock()
        self.robots: set[str] = set()
        self.total_connections = 0
        self.refused_hellos = 0
        self.conns: set[_Conn] = set()
        self.gate = ConnGate("part server", limits)
        family = socket.AF_INET6 if ":" in address[0] else socket.AF_INET
        self.sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind(address)
            self.sock.listen(backlog())
        except (OSError, OverflowError) as e:
            self.sock.close()
            if isinstance(e, OverflowError):
                raise OSError(str(e)) from None
            raise
        self.sock.setblocking(False)
        self.server_address = self.sock.getsockname()
        self.loop = asyncio.new_event_loop()
        self.ready: Future = Future()

    def connected(self, conn: str, delta: int) -> None:
        with self.lock:
            if delta > 0:
                self.robots.add(conn)
                self.total_connections += 1
            else:
                self.robots.discard(conn)

    def cut_off(self, robot: str) -> bool:
        return self.desk.is_cut_off(robot)

    def run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.gate.loop_errors(self.loop)
        try:
            server = self.loop.run_until_complete(
                self.loop.create_server(lambda: _Conn(self), sock=self.sock))
        except BaseException as e:
            self.ready.set_exception(e)
            return
        self.ready.set_result(True)
        self.loop.call_later(SWEEP_S, self._sweep)
        try:
            self.loop.run_forever()
        finally:
            server.close()
            for c in list(self.conns):
                c.close("ERR the cell controller is shutting down")
            self.loop.run_until_complete(asyncio.sleep(0.05))
            self.gate.tell()
            self.loop.close()

    def _sweep(self) -> None:
        """Close connections that never said anything, or went silent with nothing asked;
        and those of robots the desk has cut off."""
        now, lim = self.loop.time(), self.limits
        for c in list(self.conns):
            if c.closing or c.waiting:
                continue
            if c.robot and self.cut_off(c.robot):
                c.close(f"ERR robot {c.robot} is cut off: parts handed to it were never "
                        "reported")
            elif c.lines == 0 and now - c.seen > lim.header_s:
                self.gate.note(f"closed: nothing said within {lim.header_s:g} s")
                c.close()
            elif now - c.seen > lim.idle_s:
                self.gate.note(f"closed: silent for {lim.idle_s:g} s")
                c.close()
        if not self.closing.is_set():
            self.loop.call_later(SWEEP_S, self._sweep)

    def stop(self) -> None:
        self.closing.set()
        try:
            self.loop.call_soon_threadsafe(self.loop.stop)
        except RuntimeError:
            pass


class PartServer:
    """The listening socket and its thread; ``start()`` returns ``host:port``.

    ``trust``: the robots file (None: loopback peers only); ``limits``: the connection
    caps and time-outs."""

    def __init__(self, desk: Desk, host: str = "127.0.0.1", port: int = DEFAULT_PORT,
                 trust: RobotTrust | None = None, limits: ConnLimits = LIMITS) -> None:
        self.desk = desk
        self.trust = trust or RobotTrust()
        desk.max_outstanding = self.trust.max_outstanding
        self.server = _Server((host, port), desk, self.trust, limits)
        desk.alive = lambda conn: conn in self.server.robots
        self.thread = threading.Thread(target=self.server.run, name="part-server",
                                       daemon=True)

    @property
    def address(self) -> tuple[str, int]:
        host, port = self.server.server_address[:2]
        return str(host), int(port)

    def start(self) -> str:
        self.thread.start()
        self.server.ready.result(timeout=30.0)
        host, port = self.address
        return f"{host}:{port}"

    def close(self) -> None:
        """Stop accepting; waiting robots are told the controller is shutting down."""
        self.server.stop()
        self.thread.join(timeout=5.0)
        self.server.sock.close()

    def report(self) -> dict[str, Any]:
        return {"address": "{}:{}".format(*self.address),
                "connections": self.server.total_connections,
                "connection_limits": self.server.gate.stats(),
                "refused_hellos": self.server.refused_hellos, **self.desk.report()}
