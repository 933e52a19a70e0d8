"""An emulator of the Adept controller's V+ servers (``vplus/``), backed by the plant.

Four real TCP servers on loopback, one per V+ server program — motion, position, I/O and
I/O notify — speaking the protocol of ``vplus/PROTOCOL.md``. Like the V+ programs, each
serves one client at a time and, when the client goes away (READ status 101) or the link
breaks, resets its socket and waits for the next (thesis Figure 7-1). Commands act on the
plant's simulated robot; a motion holds its connection until the simulated motion ends,
so a pick takes its real time, while the position socket answers mid-motion.

As strict as the controller: it serves only V+ programs that V+ would load (``start``
runs ``vplus_check`` on ``vplus/`` and refuses with the first finding, ``FILE:LINE``), and
its replies, errors included, are those of the programs' code paths.

Fault plan (controller ``adept``): ``reject`` answers ``ERR -9005``; ``drop`` closes the
connection on receipt, before anything is done; ``drop_during`` cuts the link ``after_s``
into a motion, which runs to its end (V+ does not read the socket while it moves);
``drop_after`` finishes the command and cuts the link instead of replying; ``stall``
holds the reply back ``stall_s``; ``servo_timeout`` fails the motion with ``-1007 *Motor
stalled*`` and turns arm power off: every motion then fails with ``-604 *Robot power off*``
until the power is on again, by ``RECOVER 1`` if the cell description allows it, else by
the operator (``operator_reset``). An active e-stop input also turns power off.

What the gripper holds (``HELD``): the emulator's motion server keeps its own record, as
the V+ program does: the id of the part a PICK gripped (recorded when the PICK starts,
kept while the vacuum holds) and the id of the last part released at a place pose.
"""

from __future__ import annotations

import math
import socket
import threading
from collections import Counter, deque
from collections.abc import Callable
from pathlib import Path

from ..errors import EnvelopeError, HalError, MissedGrab
from ..hal.adept import protocol as P
from ..hal.interfaces import PickTarget, Pose
from ..jobs import Job
from .adept_io import BadArgument, IoServers, _as_flag, _as_int, _cut, _err, _num
from .faults import FaultPlan
from .plant import Plant
from .vplus_check import VPLUS_DIR, require_loadable

SERVERS = ("motion", "position", "io", "notify")
SERVO_FAULT_S = 0.25         # the arm runs into something this long after the command
MOTION_LIMIT_S = 60.0        # a simulated motion that has not ended by then: plant stopped
POLL_S = 0.1                 # how often blocked server threads look at the stop flag

MOTIONS = ("PICK", "PLACE", "MOVE", "SAFE")
ESTOP = "estop"              # the cell's e-stop input (the V+ programs' estop.in)


class AdeptEmulator(IoServers):
    """The V+ servers over ``plant``. ``start()`` returns self; ``.ports`` maps each server
    (motion, position, io, notify) to its port; ``stop()`` closes everything."""

    def __init__(self, plant: Plant, host: str = "127.0.0.1",
                 ports: dict[str, int] | None = None, faults: FaultPlan | None = None,
                 programs: Path | str | None = VPLUS_DIR, belt_direction: int = 1) -> None:
        self.plant, self.host, self.faults = plant, host, faults
        self.programs = programs                 # the V+ programs served (None: unchecked)
        self.belt_direction = belt_direction     # -1: the robot's belt channel counts down
        self.ports: dict[str, int] = {name: int((ports or {}).get(name) or 0) for name in SERVERS}
        self.power = True                        # arm power; off after a servo fault, e-stop
        self.fault = 0                           # the servo error REACTE noted (0: none)
        self.held_id = 0                         # commanded id of the part in the gripper
        self.placed_id = 0                       # id of the last part released at a place
        self.stop_requested = False              # STOP on the position socket
        self._motion_job: Job | None = None      # the plant robot's motion in progress
        self.soft: dict[int, bool] = {}          # V+ soft signals 2001-2999
        self.connections: Counter[str] = Counter()
        self.requests: deque[tuple[str, str]] = deque(maxlen=1000)   # (server, line), latest
        self._stop = threading.Event()
        self._listeners: dict[str, socket.socket] = {}
        self._threads: list[threading.Thread] = []
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._handlers: dict[str, dict[str, Callable[..., str]]] = {
            "motion": {"HELLO": lambda: self._hello("motion"), "PICK": self._pick,
                       "PLACE": self._place, "MOVE": self._move, "SAFE": self._safe,
                       "SPEED": self._speed, "RECOVER": self._recover,
                       "HOLDING": self._holding, "HELD": self._held,
                       "FRAME": lambda x, y, r: "OK", "DEFSAFE": lambda x, y, z, r: "OK",
                       "ESTOP": lambda s: "OK"},
            "position": {"HELLO": lambda: self._hello("position"), "WHERE": self._where,
                         "BELT": self._belt, "POLL": self._poll, "STOP": self._stop_robot,
                         "HERE": self._where},
            "io": {"HELLO": lambda: self._hello("io"), "SIG": self._sig, "SET": self._set},
        }

    def handled(self) -> dict[str, set[str]]:
        """The verbs each request server answers (checked against the protocol table)."""
        return {name: set(table) for name, table in self._handlers.items()}

    # ------------------------------------------------------------------ life
    def start(self) -> AdeptEmulator:
        """Serve the four sockets; refuses (``VplusRefused``, one line naming FILE:LINE) if
        the V+ programs would not load on a controller."""
        if self.programs is not None:
            require_loadable(self.programs)
        for name in SERVERS:
            lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                lsock.bind((self.host, self.ports[name]))
            except OSError:
                lsock.close()
                self.stop()
                raise
            lsock.listen(1)
            lsock.settimeout(POLL_S)
            self.ports[name] = lsock.getsockname()[1]
            self._listeners[name] = lsock
        for name, lsock in self._listeners.items():
            t = threading.Thread(target=self._serve, args=(name, lsock),
                                 name=f"adept-emu-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def stop(self) -> None:
        self._stop.set()
        for lsock in self._listeners.values():
            lsock.close()
        self.drop_clients()
        for t in self._threads:
            t.join(timeout=3.0)
        self._threads.clear()
        self._listeners.clear()

    def __enter__(self) -> AdeptEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def drop_clients(self) -> None:
        """Break every client connection (a network fault; the servers wait for new ones)."""
        with self._lock:
            conns = list(self._conns)
        for conn in conns:
            try:
                conn.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass

    # ------------------------------------------------------------------ servers
    def _serve(self, name: str, lsock: socket.socket) -> None:
        """Figure 7-1: wait for a connection (READ 100), serve it until the client closes
        (101) or the link breaks, reset the socket, wait again."""
        while not self._stop.is_set():
            try:
                conn, _ = lsock.accept()
            except TimeoutError:
                continue
            except OSError:
                return                          # listener closed: stopping
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            with self._lock:
                self._conns.add(conn)
            self.connections[name] += 1
            try:
                if name == "notify":
                    self._notify_session(conn)
                else:
                    self._request_session(name, conn)
            except OSError:
                pass                            # "socket crash": close and listen again
            finally:
                with self._lock:
                    self._conns.discard(conn)
                conn.close()

    def _request_session(self, name: str, conn: socket.socket) -> None:
        conn.settimeout(POLL_S)
        buf = b""
        while not self._stop.is_set():
            if b"\n" not in buf:
                if len(buf) > P.MAX_LINE:       # READ buffer overflow: refuse and resync
                    buf = b""
                    conn.sendall((_err(P.CODE_BAD_ARGUMENT) + "\r\n").encode())
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                if not chunk:
                    return                      # client closed (READ 101): reset
                buf += chunk
                continue
            raw, _, buf = buf.partition(b"\n")
            # strip.eol: CR and LF off the end; the verb and words as next.word splits them
            line = raw.decode("ascii", "replace").rstrip("\r\n")
            if not line.strip():
                continue
            self.requests.append((name, line))
            rule = self.faults.check("adept", line.strip()) if self.faults is not None else None
            kind = rule.kind if rule is not None else None
            if kind == "drop":
                return                          # the connection dies without a reply
            cutter = None
            if kind == "drop_during":           # the link goes while the motion runs on
                cutter = threading.Timer(rule.after_s, _cut, (conn,))   # type: ignore[union-attr]
                cutter.daemon = True
                cutter.start()
            if kind == "reject":
                reply = _err(P.CODE_REJECTED)
            else:
                reply = self._dispatch(name, line, servo_fault=kind == "servo_timeout")
            if cutter is not None:
                cutter.join()
            if kind == "drop_after":
                return                          # done, but the reply is lost with the link
            if kind == "stall":
                self._stop.wait(rule.stall_s)   # type: ignore[union-attr]
            conn.sendall((reply + "\r\n").encode("ascii"))   # V+ WRITE ends lines CR LF

    def _dispatch(self, name: str, line: str, servo_fault: bool = False) -> str:
        """decode_and_do (thesis Figure 7-2): decode the verb, check the arguments, do it,
        in the order the V+ programs do (pos.decode checks the arity before the verb)."""
        verb, *words = line.split()
        handler = self._handlers[name].get(verb)
        if name == "position" and words:
            return _err(P.CODE_BAD_ARGUMENT)
        if handler is None:
            return _err(P.CODE_UNKNOWN_REQUEST)
        cmd = P.command(name, verb)
        if len(words) != len(cmd.args):
            return _err(P.CODE_BAD_ARGUMENT)
        try:
            args = [float(w) for w in words]
            if not all(math.isfinite(a) for a in args):
                raise BadArgument("not finite")
            if servo_fault and verb in MOTIONS:
                return self._servo_fault()
            return handler(*args)
        except (ValueError, BadArgument):
            return _err(P.CODE_BAD_ARGUMENT)

    # ------------------------------------------------------------------ motion server
    def _hello(self, server: str) -> str:
        return f"OK {P.PROTOCOL_VERSION} {server}"

    def _servo_fault(self) -> str:
        """The arm runs into something: the amplifiers time out, REACTE turns power off."""
        refused = self._ready()
        if refused:
            return refused
        self._stop.wait(SERVO_FAULT_S)
        self.power = False
        self.fault = P.CODE_MOTOR_STALLED
        return _err(P.CODE_MOTOR_STALLED)

    def estop_active(self) -> bool:
        """The e-stop's hardware input (the V+ programs read it: estop.in)."""
        active = self.plant.signal(ESTOP)
        if active:
            self.power = False              # the e-stop circuit drops arm power
        return active

    def operator_reset(self) -> bool:
        """The operator turns arm power on (the pendant or front panel): refused while the
        e-stop input is active. Clears nothing else: a servo fault still needs RECOVER."""
        if self.estop_active():
            return False
        self.power = True
        return True

    def _ready(self) -> str | None:
        """motion.ready: the error a motion answers now, or None."""
        if self.estop_active():
            return _err(P.CODE_ESTOP)
        if self.fault or not self.power:
            return _err(P.CODE_POWER_OFF)
        self.stop_requested = False
        return None

    def _run(self, start: Callable[[], Job]) -> Job | str:
        """Start a simulated robot job and block this connection until it ends: a link
        lost meanwhile does not stop it (nothing reads the socket during a motion)."""
        refused = self._ready()
        if refused:
            return refused
        with self.plant.lock:
            job = start()
            self._motion_job = job
        try:
            if not self.plant.wait(job, timeout=MOTION_LIMIT_S):
                return _err(P.CODE_REJECTED)
        finally:
            self._motion_job = None
        return job

    def _pick(self, pid: float, x: float, y: float, angle: float, latch: float,
              tracking: float, ox: float, oy: float, oz: float) -> str:
        target = PickTarget(part_id=_as_int(pid), x_mm=x, y_mm=y, angle_deg=angle,
                            latch=self._from_robot_count(_as_int(latch)),
                            tracking=_as_flag(tracking), tool_offset=(ox, oy, oz))
        job = self._run(lambda: self.plant.hal.robot.pick(target))
        if isinstance(job, str):
            return job
        with self.plant.lock:               # do.pick: the vacuum switch decides
            holding = self.plant.hal.robot.holding()
        self.held_id = target.part_id if holding and job.ok else (self.held_id if holding else 0)
        if job.ok:
            return f"OK {target.part_id} {_num(job.result.belt_x_mm)}"
        return self._failed(job.error, target.tracking)

    def _failed(self, error: HalError | None, tracking: bool = False) -> str:
        if self.stop_requested:
            return _err(P.CODE_STOPPED)
        if isinstance(error, EnvelopeError):    # V+: WINDOW() check, or out of reach
            return _err(P.CODE_OUTSIDE_WINDOW if tracking else P.CODE_OUT_OF_RANGE)
        if isinstance(error, MissedGrab):
            return _err(P.CODE_NOTHING_GRIPPED)
        return _err(P.CODE_REJECTED)

    def _motion_reply(self, job: Job | str) -> str:
        if isinstance(job, str):
            return job
        return "OK" if job.ok else self._failed(job.error)

    def _place(self, x: float, y: float, z: float, rz: float) -> str:
        job = self._run(lambda: self.plant.hal.robot.place(Pose(x, y, z, rz)))
        if not isinstance(job, str) and job.ok:
            self.placed_id, self.held_id = self.held_id, 0     # released at the pose
        return self._motion_reply(job)

    def _move(self, x: float, y: float, z: float, rz: float) -> str:
        return self._motion_reply(self._run(lambda: self.plant.hal.robot.move_to(Pose(x, y, z, rz))))

    def _safe(self) -> str:
        return self._motion_reply(self._run(lambda: self.plant.hal.robot.move_safe()))

    def _speed(self, pct: float) -> str:
        if not 0.0 < pct <= 200.0:
            raise BadArgument(f"speed {pct} %")
        with self.plant.lock:
            self.plant.hal.robot.set_speed(pct)
        return "OK"

    def _recover(self, power: float) -> str:
        """reacte.v2 arm.recover: clear the fault; power on again only with ``power`` 1 (the
        cell description's rule), else the operator must (``operator_reset``)."""
        allowed = _as_flag(power)
        if self.fault:
            with self.plant.lock:
                job = self.plant.hal.robot.recover()
            self.plant.wait(job, timeout=MOTION_LIMIT_S)
            if not job.ok:
                return self._failed(job.error)
        self.fault = 0
        self.stop_requested = False
        if self.estop_active():
            return _err(P.CODE_ESTOP)
        if allowed:
            self.power = True
        return "OK" if self.power else _err(P.CODE_POWER_OFF)

    def _holding(self) -> str:
        with self.plant.lock:
            held = self.plant.hal.robot.holding()
        return f"OK {int(held)}"

    def _held(self) -> str:
        """do.held: the commanded id while the vacuum holds (-1: ours never gripped it)."""
        with self.plant.lock:
            holding = self.plant.hal.robot.holding()
        if not holding:
            self.held_id = 0
        h = (self.held_id or -1) if holding else 0
        return f"OK {h} {self.placed_id}"

    # ------------------------------------------------------------------ position server
    def _robot_count(self) -> int:
        """The count the robot's belt channel shows: reversed if wired backwards."""
        with self.plant.lock:
            count = self.plant.hal.robot_position.belt_encoder()
        return P.wrap_robot(count * self.belt_direction)

    def _from_robot_count(self, count: int) -> int:
        return P.wrap_robot(count * self.belt_direction)

    def _where(self) -> str:
        with self.plant.lock:
            p = self.plant.hal.robot_position.pose()
        return f"OK {_num(p.x)} {_num(p.y)} {_num(p.z)} {_num(p.rz)}"

    def _belt(self) -> str:
        return f"OK {self._robot_count()}"

    def _poll(self) -> str:
        return f"{self._where()} {self._robot_count()}"

    def _stop_robot(self) -> str:
        """STOP: BRAKE the motion in progress. A pick ends at once (nothing gripped); the
        simulated place cannot stop half-way, so it finishes (a V+ place stops with the
        part held): either way HELD tells what the gripper holds."""
        self.stop_requested = True
        with self.plant.lock:
            job = self._motion_job
            if job is not None and not job.done and job.name != "robot.place":
                job.cancel()
        return "OK"

def serve(plant: Plant, host: str = "127.0.0.1", ports: dict[str, int] | int | None = None,
          faults: FaultPlan | None = None, **kw) -> AdeptEmulator:
    """Start the V+ emulator: ``ports`` a dict per server, or N for ports N..N+3 (motion,
    position, io, notify), or None for free ports. ``feeder emulate adept --port N``."""
    if isinstance(ports, int):
        ports = {name: ports + i for i, name in enumerate(SERVERS)}
    return AdeptEmulator(plant, host=host, ports=ports, faults=faults, **kw).start()
