"""``feeder run --part-server ... --no-sim-robot --sim-robot-port [HOST:]PORT``: an outside
program drives the simulated robot (docs/part-server.md, "Your own robot
program on the simulated cell").

Without a simulated robot program nothing moves the simulated robot, so a client that
reports ``PLACED`` is not believed (a mismatch). This port lets a program in another
process move the simulated robot itself, one motion at a time, over lines of text, the
way a robot controller would be driven; the world judges every grip against the truth,
exactly as for the built-in program. The motions (one reply each, when the motion ends):

    PICK ID X Y RZ LATCH      -> OK PICK ID        | ERR PICK ID KIND: message
    PLACE TYPE RZ             -> OK PLACE          | ERR PLACE KIND: message
    SAFE                      -> OK SAFE
    RECOVER                   -> OK RECOVER
    HELD                      -> OK HELD ID|-      (what the gripper holds)
    SPEED PCT                 -> OK SPEED PCT

``PICK`` takes the part server's offer fields as they are (tracking as the scenario says);
``PLACE`` puts the held part at the place pose of its type. A simulator's port: loopback
only, connections gated like every listener (``ui.conns``). The tick thread starts and
polls the motions (``pump``); the port's thread only reads and writes lines.
"""

from __future__ import annotations

import asyncio
import math
import threading
from collections import deque
from concurrent.futures import Future
from typing import Any

from feeder_bt.control.conns import ConnGate, ConnLimits, backlog
from feeder_bt.core.errors import FeederError
from feeder_bt.core.jobs import Job, JobState
from feeder_bt.hal.interfaces import PickTarget, Pose
from feeder_bt.plant.ua_security import is_loopback

MAX_LINE = 200


class _Port(asyncio.Protocol):
    def __init__(self, owner: RobotPort) -> None:
        self.owner, self.transport, self.buf = owner, None, b""

    def connection_made(self, transport: Any) -> None:
        if self.owner.gate.admit(transport, lambda: True):
            self.transport = transport

    def connection_lost(self, exc: Exception | None) -> None:
        if self.transport is not None:
            self.owner.gate.release(self.transport)

    def data_received(self, data: bytes) -> None:
        self.buf += data
        while b"\n" in self.buf:
            raw, _, self.buf = self.buf.partition(b"\n")
            line = raw[:MAX_LINE].decode("ascii", "replace").strip()
            self.owner.inbox.append((line, self._reply))
        if len(self.buf) > MAX_LINE:
            self.buf = b""
            self._reply("ERR line too long")

    def _reply(self, text: str) -> None:         # tick thread
        def write() -> None:
            if self.transport is not None and not self.transport.is_closing():
                self.transport.write(text.encode("ascii", "replace") + b"\n")
        try:
            self.owner.loop.call_soon_threadsafe(write)
        except RuntimeError:
            pass


class RobotPort:
    """The simulated robot behind a line port; ``pump()`` after every tick."""

    def __init__(self, robot: Any, scenario: Any, host: str, port: int) -> None:
        if not is_loopback(host):
            raise FeederError(f"--sim-robot-port {host}:{port}: the simulated robot's port "
                              "is for this machine only (127.0.0.1)")
        self.robot, self.scenario = robot, scenario
        self.inbox: deque[tuple[str, Any]] = deque()
        self.job: tuple[str, Job, Any] | None = None     # (command, job, reply)
        self.held_type: str | None = None
        self.gate = ConnGate("simulated robot port", ConnLimits(total=8, per_address=8))
        self.loop = asyncio.new_event_loop()
        self.ready: Future = Future()
        self.sock_args = (host, port)
        self.server: Any = None
        self.thread = threading.Thread(target=self._run, name="robot-port", daemon=True)
        self.counts = {"picks": 0, "places": 0, "refused": 0}

    def start(self) -> str:
        self.thread.start()
        self.ready.result(timeout=30.0)
        host, port = self.server.sockets[0].getsockname()[:2]
        return f"{host}:{port}"

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.gate.loop_errors(self.loop)
        try:
            self.server = self.loop.run_until_complete(self.loop.create_server(
                lambda: _Port(self), *self.sock_args, backlog=backlog()))
        except OSError as e:
            self.ready.set_exception(e)
            return
        self.ready.set_result(True)
        try:
            self.loop.run_forever()
        finally:
            self.server.close()
            self.loop.close()

    def close(self) -> None:
        try:
            self.loop.call_soon_threadsafe(self.loop.stop)
        except RuntimeError:
            pass
        self.thread.join(timeout=5.0)

    # ------------------------------------------------------------------ tick thread
    def pump(self) -> None:
        """Finish the running motion (reply), then start the next request."""
        if self.job is not None:
            cmd, job, reply = self.job
            if job.poll() is JobState.RUNNING:
                return
            self.job = None
            reply(self._outcome(cmd, job))
        while self.inbox and self.job is None:
            line, reply = self.inbox.popleft()
            try:
                started = self._start(line)
            except (ValueError, IndexError, KeyError) as e:
                self.counts["refused"] += 1
                reply(f"ERR {line.split()[0] if line.split() else '?'}: {e}"[:200])
                continue
            if isinstance(started, str):
                reply(started)
            else:
                self.job = (line, started, reply)

    def _start(self, line: str) -> Job | str:
        words = line.split()
        cmd = words[0].upper() if words else ""
        r = self.robot
        if cmd == "PICK":
            pid, x, y, rz, latch = (int(words[1]), *_finite(words[2:5]), int(words[5]))
            self.counts["picks"] += 1
            return r.pick(PickTarget(part_id=pid, x_mm=x, y_mm=y, angle_deg=rz, latch=latch,
                                     tracking=self.scenario.retrieve.tracking))
        if cmd == "PLACE":
            spec = self.scenario.parts[words[1]].place
            (rz,) = _finite(words[2:3])
            self.counts["places"] += 1
            return r.place(Pose(spec.x, spec.y, spec.z, -rz if spec.orient else 0.0))
        if cmd == "SAFE":
            return r.move_safe()
        if cmd == "RECOVER":
            return r.recover()
        if cmd == "HELD":
            return r.held()
        if cmd == "SPEED":
            (pct,) = _finite(words[1:2])
            if not 1.0 <= pct <= 200.0:
                raise ValueError("speed 1-200 %")
            r.set_speed(pct)
            return f"OK SPEED {pct:g}"
        raise ValueError("one of PICK, PLACE, SAFE, RECOVER, HELD, SPEED")

    def _outcome(self, line: str, job: Job) -> str:
        words = line.split()
        cmd = words[0].upper()
        if not job.ok:
            err = job.error
            kind = getattr(err, "kind", "failed")
            what = f"{cmd} {words[1]}" if cmd == "PICK" else cmd
            return f"ERR {what} {kind}: {str(err)[:120]}"
        if cmd == "PICK":
            return f"OK PICK {words[1]}"
        if cmd == "HELD":
            held = job.result
            pid = getattr(held, "part_id", None)
            return f"OK HELD {pid if pid is not None else '-'}"
        return f"OK {cmd}"


def _finite(words: list[str]) -> list[float]:
    out = []
    for w in words:
        if len(w) > 32 or not w.isascii():
            raise ValueError(f"not a number: {w[:32]!r}")
        v = float(w)
        if not math.isfinite(v):
            raise ValueError(f"not a finite number: {w!r}")
        out.append(v)
    if not out:
        raise ValueError("a number is missing")
    return out
