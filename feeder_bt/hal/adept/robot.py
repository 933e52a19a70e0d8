"""The robot, its position and its I/O behind the HAL interfaces, over the V+ servers.

Every call returns at once: motions and settings are requests queued on the socket's
worker and returned as ``FutureJob``s; reads (``holding``, ``pose``, ``belt_encoder``,
``get``) come from caches that the replies, a position poller and the notify listener
keep up to date (thesis chapter 6: position server, I/O server with ``adept_io_notify``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterable

from feeder_bt.core.clock import Clock, sampled_at
from feeder_bt.core.errors import CommsLost, HalError, MissedGrab
from feeder_bt.core.jobs import DoneJob, FutureJob, Job
from feeder_bt.hal.adept import protocol
from feeder_bt.hal.adept.client import LineSocket, ServerClient
from feeder_bt.hal.interfaces import Held, PickResult, PickTarget, Pose

POLL_S = 0.02                # position poller period: 50 Hz (adept.poll_hz), one POLL each


class PlaceJob(FutureJob):
    """A place is never abandoned (interface contract): cancelling it lets the controller
    finish the place, and the job ends SUCCEEDED when the reply comes."""

    def cancel(self) -> None:
        pass


class AdeptRobot:
    """``Robot`` over the motion server. ``holding()`` is local state set by the replies;
    ``held()`` asks the controller (after a lost reply).

    ``stopper``: the position server, which answers while a motion runs: a motion request
    that times out first STOPs the robot there, then drops the motion socket, so the arm
    does not keep moving unwatched. ``recover_power_on``: the cell description's rule
    whether RECOVER may turn arm power on (else the operator does). ``belt_sign``: -1 when
    the robot's belt channel counts down as the belt runs forward."""

    def __init__(self, motion: ServerClient, clock: Clock, motion_timeout_s: float,
                 timeout_s: float, stopper: ServerClient | None = None,
                 recover_power_on: bool = False, belt_sign: int = 1) -> None:
        self.motion, self.clock = motion, clock
        self.motion_timeout_s, self.timeout_s = motion_timeout_s, timeout_s
        self.stopper, self.recover_power_on, self.belt_sign = stopper, recover_power_on, belt_sign
        self._holding = False
        self._speed_pct = 100.0                 # as last set: motions slow down with it
        self.stops = 0                          # STOPs sent on time-outs (tests, logs)

    def refresh_holding(self) -> bool:
        """Ask the controller whether the gripper holds a part (blocking: start-up only)."""
        values = self.motion.call("HOLDING", timeout=self.timeout_s)
        self._holding = protocol.decode_flag(values, "HOLDING")
        return self._holding

    def _submit(self, name: str, run, cls: type[FutureJob] = FutureJob) -> Job:
        try:
            future = self.motion.worker.submit(run)
        except RuntimeError as e:                   # the controller was closed
            return DoneJob(name, error=CommsLost(f"{name}: {e}"))
        return cls(name, future, self.clock)

    def _call(self, verb: str, *args: object, motion: bool = True) -> list[str]:
        timeout = self.motion_deadline_s() if motion else self.timeout_s
        stop = self._stop_now if motion and verb != "HELD" else None
        try:
            return self.motion.call(verb, *args, timeout=timeout, on_timeout=stop)
        except CommsLost:
            if verb in ("PICK", "PLACE"):
                # the motion may have finished without us hearing: ask the controller
                # what the gripper holds as soon as the link is back, before anything else
                self.motion.worker.submit(self._refresh_after_link_loss)
            raise

    def motion_deadline_s(self) -> float:
        """How long a motion's reply may take: ``motion_timeout_s`` at full speed, longer
        in proportion at a lower speed. A reply lost in a half-open link (a pulled cable,
        no FIN) is found by this deadline, so it is the longest a motion may take, no more."""
        return self.motion_timeout_s * max(1.0, 100.0 / max(self._speed_pct, 1.0))

    def _refresh_after_link_loss(self) -> None:
        try:
            self._held()
        except HalError:
            pass                # still down: the next PICK/PLACE failure asks again

    def _stop_now(self) -> None:
        """STOP on the position socket (blocking; a motion request timed out)."""
        if self.stopper is None:
            return
        self.stops += 1
        try:
            self.stopper.call("STOP", timeout=self.timeout_s)
        except HalError:
            pass                # the controller is unreachable: the link loss is reported

    def stop(self) -> Job:
        """Halt the robot now (the cell's stop): STOP on the position socket, which answers
        while the motion socket waits for the motion's end."""
        if self.stopper is None:
            return DoneJob("robot.stop", error=HalError("no position socket to send STOP on"))
        try:
            future = self.stopper.submit("STOP", timeout=self.timeout_s)
        except RuntimeError as e:
            return DoneJob("robot.stop", error=CommsLost(f"robot.stop: {e}"))
        return FutureJob("robot.stop", future, self.clock)

    def _held(self) -> Held:
        held = protocol.decode_held(self._call("HELD"))
        self._holding = not held.empty
        return held

    def held(self) -> Job:
        """HELD: what the gripper holds, as the controller knows it (result ``Held``). Queued
        behind any request in flight; the controller answers after a motion still running."""
        return self._submit("robot.held", self._held)

    def pick(self, target: PickTarget) -> Job:
        if int(target.part_id) <= 0:        # HELD's 0 and -1 mean "nothing", "not ours"
            return DoneJob("robot.pick", error=HalError(
                f"part id {target.part_id}: the controller needs a positive id"))
        ox, oy, oz = target.tool_offset

        def run() -> PickResult:
            latch = protocol.wrap_robot(int(target.latch) * self.belt_sign)  # its own count
            try:
                # grip: the tool's turn from the part's angle at the grip
                # (``PickTarget.grip_deg``); the controller keeps it for the PLACE
                values = self._call("PICK", int(target.part_id), float(target.x_mm),
                                    float(target.y_mm), float(target.angle_deg),
                                    latch, bool(target.tracking),
                                    float(ox), float(oy), float(oz),
                                    float(target.grip_deg))
            except MissedGrab:
                self._holding = False
                raise
            part_id, x_mm = protocol.decode_pick(values)
            self._holding = True
            return PickResult(part_id=part_id, t=self.clock.now(), belt_x_mm=x_mm)

        return self._submit("robot.pick", run)

    def place(self, pose: Pose) -> Job:
        def run() -> None:
            self._call("PLACE", *_pose_args(pose))
            self._holding = False

        return self._submit("robot.place", run, cls=PlaceJob)

    def move_to(self, pose: Pose) -> Job:
        def run() -> Pose:
            self._call("MOVE", *_pose_args(pose))
            return pose

        return self._submit("robot.move", run)

    def move_safe(self) -> Job:
        def run() -> None:
            self._call("SAFE")

        return self._submit("robot.move_safe", run)

    def set_speed(self, pct: float) -> Job:
        def run() -> None:
            self._call("SPEED", float(pct), motion=False)
            self._speed_pct = float(pct)

        return self._submit("robot.set_speed", run)

    def recover(self) -> Job:
        """RECOVER runs the V+ recovery (reacte.v2 arm.recover); arm power comes on again
        only if the cell description allows it (``recover_power_on``), else the job fails
        with -604 until the operator has turned it on. Then re-read what is held."""
        def run() -> None:
            self._call("RECOVER", self.recover_power_on)
            self.refresh_holding()

        return self._submit("robot.recover", run)

    def holding(self) -> bool:
        return self._holding


def _pose_args(pose: Pose) -> tuple[float, float, float, float]:
    return float(pose.x), float(pose.y), float(pose.z), float(pose.rz)


class AdeptRobotPosition:
    """``RobotPosition`` over the position server: a poller refreshes a cache with one POLL
    (pose and belt count in one round trip) ``1/period_s`` times a second (its own socket,
    so it reads on while the robot moves); reads return the cache. ``belt_sign`` -1: the
    robot's belt channel counts down as the belt runs forward; the cache holds the count
    turned forward, and PICK turns a latch back into the channel's own count."""

    def __init__(self, position: ServerClient, period_s: float = POLL_S,
                 belt_sign: int = 1) -> None:
        self.position = position
        self.period_s = period_s
        self.belt_sign = belt_sign
        self.polls = 0                            # POLL round trips (tests, load figures)
        self._pose = Pose(0.0, 0.0)
        self._count = 0
        self.updated_at: float | None = None      # monotonic time of the last good read
        self.rtt = 0.0                            # that read's round trip (s)
        self.error: HalError | None = None        # the last failure, None once reading again
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def read_once(self) -> None:
        """One POLL (blocking; the poller thread, or start-up)."""
        t0 = time.monotonic()
        pose, count = protocol.decode_poll(self.position.call("POLL"))
        self.polls += 1
        self._pose, self._count = pose, protocol.wrap_robot(count * self.belt_sign)
        t1 = time.monotonic()
        self.updated_at = sampled_at(t0, t1)
        self.rtt = t1 - t0                        # when the count was sampled: +- half of it
        self.error = None

    def start(self) -> AdeptRobotPosition:
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="vplus-position-poll",
                                            daemon=True)
            self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.read_once()
            except HalError as e:
                self.error = e                  # keep the last good values; retry
            self._stop.wait(self.period_s)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def belt_encoder(self) -> int:
        return self._count

    def pose(self) -> Pose:
        return self._pose

    def age(self) -> float | None:
        """Seconds since the cache was last refreshed (None: never)."""
        return None if self.updated_at is None else time.monotonic() - self.updated_at


class AdeptIO:
    """The Adept controller's digital I/O by the cell description's bit numbers.

    Inputs: a cache filled by an initial read and kept by the notify socket (``IN`` lines);
    ``changes()`` drains ``(bit, value, t)`` tuples. Outputs: ``SET`` on the I/O socket,
    remembered locally (the thesis's output map).
    """

    def __init__(self, io: ServerClient, notify: LineSocket, clock: Clock,
                 inputs: Iterable[int] = ()) -> None:
        self.io, self.notify, self.clock = io, notify, clock
        self.inputs = set(inputs)
        self.declared = set(inputs)              # the cell description's inputs
        self._in: dict[int, bool] = {}
        self._out: dict[int, bool] = {}
        self._changes: list[tuple[int, bool, float]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: HalError | None = None
        self.connected = threading.Event()       # the notify socket has sent its states

    # ------------------------------------------------------------------ reads
    def read_inputs(self) -> None:
        """Read every known input once (blocking; start-up)."""
        for bit in sorted(self.inputs):
            values = self.io.call("SIG", protocol.signal_of(bit, True))
            self._note(bit, protocol.decode_flag(values, "SIG"), initial=True)

    def _note(self, bit: int, value: bool, initial: bool = False) -> None:
        with self._lock:
            old = self._in.get(bit)
            self._in[bit] = value
            if old is not None and old != value and not initial:
                self._changes.append((bit, value, self.clock.now()))

    def get(self, bit: int) -> bool:
        with self._lock:
            # an output we set wins over an input of the same bit number that io_notify
            # reports (it watches inputs 1001..1012 whatever the cell wires)
            if bit in self._out and bit not in self.declared:
                return self._out[bit]
            if bit in self._in:
                return self._in[bit]
            return self._out.get(bit, False)

    def set(self, bit: int, value: bool) -> Job:
        name = f"io.set({bit})"
        signal = protocol.signal_of(bit, False)

        def done(values: list[str]) -> None:
            with self._lock:
                self._out[bit] = bool(value)

        try:
            future = self.io.submit("SET", signal, bool(value), then=done)
        except RuntimeError as e:                   # the controller was closed
            return DoneJob(name, error=CommsLost(f"{name}: {e}"))
        return FutureJob(name, future, self.clock)

    def changes(self) -> list[tuple[int, bool, float]]:
        with self._lock:
            out, self._changes = self._changes, []
        return out

    # ------------------------------------------------------------------ notify listener
    def start(self) -> AdeptIO:
        if self._thread is None:
            self._thread = threading.Thread(target=self._listen, name="vplus-io-notify",
                                            daemon=True)
            self._thread.start()
        return self

    def _listen(self) -> None:
        """Read ``IN`` lines; on a drop, re-connect with back-off (the server sends every
        input's state again on connection, so the cache catches up)."""
        link = self.notify
        while not self._stop.is_set():
            try:
                link.ensure(time.monotonic() + 0.5, idle_check=False)
                line = link.read_line(time.monotonic() + 0.5, "notification", idle_ok=True)
                if line is None:
                    continue
                signal, value = protocol.parse_notify(line)
            except CommsLost as e:              # wait out the link's back-off, re-connect
                self.error = e
                self.connected.clear()
                self._stop.wait(max(0.02, link.backoff.next_try - time.monotonic()))
                continue
            except HalError as e:               # a garbled line: start the link afresh
                self.error = e
                link.drop()
                continue
            bit, is_input = protocol.bit_of(signal)
            if is_input:
                self.inputs.add(bit)
                self._note(bit, value)
                self.connected.set()
            self.error = None

    def stop(self) -> None:
        self._stop.set()
        self.notify.close()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
