"""A driver for an AnyFeeder-class plate feeder over its serial line.

One device worker (a single-thread executor, as the Galil driver keeps one per
controller) owns the port: each action is written there and its replies read until every
motor that said busy (``m11``/``m21``) has said done (``m10``/``m20``), so the feeder never
sees a command while it is busy. Any error code ends the action with a ``PlateFault`` in
one line with the manual's words (Table 3-5); a silent feeder, after the action's own time
and ``plate.timeout_s``, is a fault too. A broken port is ``CommsLost``; the next action
opens it again. The port is ``serial.serial_for_url``: a device (``/dev/ttyS0``) or a
serial-to-Ethernet bridge (``socket://HOST:PORT``).
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import serial

from feeder_bt.core.clock import Clock
from feeder_bt.core.errors import CommsLost, HalError, PlateFault
from feeder_bt.core.jobs import DoneJob, FutureJob, Job
from feeder_bt.core.plate_model import PlateSpec
from feeder_bt.hal.anyfeeder.protocol import (
    BUSY,
    CR,
    DONE,
    ProtocolError,
    Reply,
    command_line,
    parse_reply,
)
from feeder_bt.hal.interfaces import PlateStatus

READ_POLL_S = 0.05


class AnyFeeder:
    """The ``PlateFeeder`` of a real (or emulated) AnyFeeder."""

    def __init__(self, spec: PlateSpec, clock: Clock) -> None:
        if not spec.url:
            raise HalError("plate.url is empty: the feeder's serial device or "
                           "socket://HOST:PORT (cell file, plate: url)")
        self.spec, self.clock = spec, clock
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="anyfeeder")
        self._ser: serial.SerialBase | None = None
        self._lock = threading.Lock()
        self._pending = 0
        self.initialised = False
        self.last_fault: HalError | None = None
        self.log: list[str] = []            # the lines exchanged, for tests and the doc

    # ------------------------------------------------------------------ the jobs
    def init(self) -> Job:
        return self._submit("plate.init", self.spec.commands.init, None, self.spec.init_s,
                            on_ok=self._homed)

    def reset(self) -> Job:
        def cleared() -> None:
            self.initialised = False          # the drives are homed again after a reset
        return self._submit("plate.reset", self.spec.commands.reset, None, 1.0,
                            on_ok=cleared)

    def dispense(self, reps: int) -> Job:
        return self._action("plate.dispense", self.spec.commands.dispense, reps)

    def feed(self, direction: int, reps: int) -> Job:
        c = self.spec.commands
        return self._action(f"plate.feed({direction:+d})",
                            c.feed_forward if direction >= 0 else c.feed_backward, reps)

    def flip(self, reps: int, direction: int = 0) -> Job:
        c = self.spec.commands
        number = c.flip if direction == 0 else (c.flip_forward if direction > 0
                                                else c.flip_backward)
        return self._action("plate.flip", number, reps)

    def purge(self, reps: int) -> Job:
        return self._action("plate.purge", self.spec.commands.purge, reps, hi=127)

    def status(self) -> PlateStatus:
        with self._lock:
            return PlateStatus(self.initialised, self._pending > 0, self.last_fault)

    def close(self) -> None:
        self._worker.shutdown(wait=True, cancel_futures=True)
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:                 # noqa: BLE001 - closing a broken port
                pass

    # ------------------------------------------------------------------ the worker
    def _homed(self) -> None:
        self.initialised = True

    def _action(self, name: str, number: int, reps: int, hi: int = 10) -> Job:
        if not 1 <= reps <= hi:               # Table 3-2: [turns] 1...10, purge 1...127
            return DoneJob(name, error=HalError(f"{name}: {reps} repetitions; the "
                                                f"AnyFeeder takes 1...{hi}"))
        duration = reps * self.spec.rep_s + self.spec.settle_s
        return self._submit(name, number, reps, duration)

    def _submit(self, name: str, number: int, value: int | None, duration: float,
                on_ok=None) -> Job:
        with self._lock:
            self._pending += 1
        line = command_line(number, value)
        future = self._worker.submit(self._exchange, name, line, duration, on_ok)
        return FutureJob(name, future, self.clock)

    def _port(self) -> serial.SerialBase:
        if self._ser is None:
            try:
                self._ser = serial.serial_for_url(self.spec.url, baudrate=self.spec.baud,
                                                  timeout=READ_POLL_S)
            except (serial.SerialException, OSError, ValueError) as e:
                raise CommsLost(f"AnyFeeder at {self.spec.url}: cannot open: {e}") from e
        return self._ser

    def _drop(self, why: str) -> CommsLost:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:                 # noqa: BLE001
                pass
        self._ser = None
        return CommsLost(f"AnyFeeder at {self.spec.url}: {why}")

    def _exchange(self, name: str, line: bytes, duration: float, on_ok) -> None:
        try:
            self._run(name, line, duration)
            if on_ok is not None:
                on_ok()
            with self._lock:
                self.last_fault = None
        except HalError as e:
            with self._lock:
                self.last_fault = e
            raise
        finally:
            with self._lock:
                self._pending -= 1

    def _run(self, name: str, line: bytes, duration: float) -> None:
        ser = self._port()
        try:
            ser.reset_input_buffer()
            ser.write(line)
        except (serial.SerialException, OSError) as e:
            raise self._drop(f"write failed: {e}") from e
        self.log.append("> " + line.decode("ascii").rstrip("\r"))
        deadline = time.monotonic() + duration + self.spec.timeout_s
        busy: set[int] = set()
        done: set[int] = set()
        buf = b""
        while True:
            if time.monotonic() > deadline:
                raise PlateFault(f"AnyFeeder {name}: no completion in "
                                 f"{duration + self.spec.timeout_s:g} s (motors done: "
                                 f"{sorted(done) or 'none'})")
            try:
                chunk = ser.read(64)
            except (serial.SerialException, OSError) as e:
                raise self._drop(f"read failed: {e}") from e
            buf += chunk
            while CR in buf:
                raw, buf = buf.split(CR, 1)
                text = raw.decode("ascii", "replace").strip()
                if not text:
                    continue
                self.log.append("< " + text)
                try:
                    reply = parse_reply(text)
                except ProtocolError as e:
                    raise self._drop(str(e)) from e
                self._judge(name, reply, busy, done)
            if done and busy <= done:
                return

    @staticmethod
    def _judge(name: str, reply: Reply, busy: set[int], done: set[int]) -> None:
        if reply.code == BUSY:
            busy.add(reply.motor)
        elif reply.code == DONE:
            done.add(reply.motor)
        else:
            raise PlateFault(f"AnyFeeder {name}: {reply.describe()}")
