"""A driver for an AnyFeeder-class plate feeder over its serial line.

One device worker (a single-thread executor, as the Galil driver keeps one per controller)
owns the port, so no leaf ever blocks on it. Each action is written there and its replies
read until *both* motors have reported (Table 3-6 lists all four codes of a standard
response, in either order and some time apart; anyfeeder_connector reads four): a motor
that said done while the other is still busy does not end the action, so nothing is
written while a motor is busy. Before each command the line is read until it has been
quiet for ``plate.quiet_s``: a late code (an ``m28`` after the action ended) is reported
as that action's fault, never dropped with an input buffer. A feeder that echoes each
command (as anyfeeder_connector expects) is found at connect and its echo skipped. Any
error code ends the action with a ``PlateFault`` in one line with the manual's words; no
completion within the action's time and ``plate.timeout_s`` is a fault too. A broken port,
a line of more than ``LINE_CAP`` bytes without ``<cr>`` or text that is no reply is
``CommsLost``; the next action opens the port again. Cancelling a running action writes
the stop command and waits for the motors before the next command. The port is
``serial.serial_for_url``: a device (``/dev/ttyS0``) or a serial-to-Ethernet bridge
(``socket://HOST:PORT``).
"""

from __future__ import annotations

import dataclasses
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import serial

from feeder_bt.core.clock import Clock
from feeder_bt.core.errors import CommsLost, HalError, JobCancelled, PlateFault
from feeder_bt.core.jobs import DoneJob, FutureJob, Job
from feeder_bt.core.plate_model import PlateSpec
from feeder_bt.hal.anyfeeder.protocol import (
    BUSY,
    CR,
    DONE,
    LINE_CAP,
    MOTORS,
    PURGE_TURNS,
    SPEED_OFFSET,
    TURNS,
    ProtocolError,
    Reply,
    command_line,
    is_reply,
    parse_reply,
    set_line,
    shown,
)
from feeder_bt.hal.interfaces import PlateStatus

READ_POLL_S = 0.02       # one read's wait: how often the worker looks at a cancel


class PlateJob(FutureJob):
    """A plate job whose cancel reaches the worker: a running action is stopped there."""

    def __init__(self, name: str, future: Future, clock: Clock,
                 cancel: threading.Event) -> None:
        super().__init__(name, future, clock)
        self._cancel = cancel

    def _on_cancel(self) -> None:
        self._cancel.set()
        super()._on_cancel()


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
        # the worker's own (only it touches them)
        self._buf = b""
        self._sent = ""                     # the last line written, to know its echo
        self._recent: deque[str] = deque(maxlen=4)    # and the few before it
        self._owed: dict[int, str] = {}     # motor -> the action it is still busy with
        self._carry: list[str] = []         # lines read after an exchange's end
        self._unacked: set[int] = set()     # motors done that never said busy
        self._last_rx = 0.0                 # when bytes last came
        self.echo: bool | None = None       # found at connect (None: not connected yet)
        self.probe: list[str] = []          # what the feeder answered to the echo probe
        self.params: dict[str, dict[str, Any]] = {}   # written after init: read-back

    # ------------------------------------------------------------------ the jobs
    def connect(self) -> Job:
        """Open the port and probe for an echo (commissioning's first step; any action
        does it too)."""
        return self._job("plate.connect", lambda cancel: self._connected())

    def init(self) -> Job:
        return self._exec("plate.init", self.spec.commands.init, None, self.spec.init_s,
                          after=self._homed)

    def reset(self) -> Job:
        """Error reset (anyfeeder_connector: "Reset error status and move AnyFeeder to
        home position"); the trees home after it all the same."""
        return self._exec("plate.reset", self.spec.commands.reset, None, self.spec.init_s)

    def restart(self) -> Job:
        """Firmware restart: the parameters return to their defaults (Table 3-7), so
        the feeder must be initialised (and the cell's parameters written) again."""
        def lost() -> None:
            self.initialised = False
        return self._exec("plate.restart", self.spec.commands.restart, None,
                          self.spec.init_s, after=lost)

    def stop(self) -> Job:
        """The stop command on an idle feeder (a running action is stopped by
        cancelling its job)."""
        return self._exec("plate.stop", self.spec.commands.stop, None, 0.0)

    def dispense(self, reps: int) -> Job:
        return self._action("plate.dispense", self.spec.commands.dispense, reps)

    def heavy_dispense(self, reps: int) -> Job:
        return self._action("plate.heavy_dispense", self.spec.commands.heavy_dispense, reps)

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
        return self._action("plate.purge", self.spec.commands.purge, reps, PURGE_TURNS)

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

    # ------------------------------------------------------------------ submitting
    def _homed(self) -> None:
        self._write_params()
        self.initialised = True

    def _action(self, name: str, number: int, reps: int,
                turns: tuple[int, int] = TURNS) -> Job:
        lo, hi = turns                        # Table 3-2: [turns] 1...10, purge 1...127
        if not lo <= reps <= hi:
            return DoneJob(name, error=HalError(f"{name}: {reps} repetitions; the "
                                                f"AnyFeeder takes {lo}...{hi}"))
        duration = reps * self.spec.rep_s + self.spec.settle_s
        return self._exec(name, number, reps, duration)

    def _exec(self, name: str, number: int, value: int | None, duration: float,
              after: Callable[[], None] | None = None) -> Job:
        line = command_line(number, value)

        def run(cancel: threading.Event) -> list[str]:
            codes = self._exchange(name, line, duration, cancel)
            if after is not None:
                after()
            return codes                      # the job's result: the motor codes seen
        return self._job(name, run)

    def _job(self, name: str, fn: Callable[[threading.Event], Any]) -> Job:
        with self._lock:
            self._pending += 1
        cancel = threading.Event()
        future = self._worker.submit(self._guarded, fn, cancel)
        future.add_done_callback(self._one_less)     # run, failed or cancelled unrun
        return PlateJob(name, future, self.clock, cancel)

    def _one_less(self, _future: Future) -> None:
        with self._lock:
            self._pending -= 1

    def _guarded(self, fn: Callable[[threading.Event], Any], cancel: threading.Event) -> Any:
        try:
            result = fn(cancel)
        except JobCancelled:
            raise
        except HalError as e:
            with self._lock:
                self.last_fault = e
            raise
        with self._lock:
            self.last_fault = None
        return result

    # ------------------------------------------------------------------ the port
    def _port(self) -> serial.SerialBase:
        if self._ser is None:
            try:
                self._ser = serial.serial_for_url(self.spec.url, baudrate=self.spec.baud,
                                                  timeout=READ_POLL_S)
            except (serial.SerialException, OSError, ValueError) as e:
                raise CommsLost(f"AnyFeeder at {self.spec.url}: cannot open: {e}") from e
            self._buf, self._owed, self._carry = b"", {}, []
            self._last_rx = time.monotonic()
            self._probe_echo()
        return self._ser

    def _connected(self) -> dict[str, Any]:
        self._port()
        return {"url": self.spec.url, "baud": self.spec.baud, "echo": self.echo,
                "probe": list(self.probe)}

    def _probe_echo(self) -> None:
        """Write a parameter set, which the feeder does not answer (Rev. A p. 31): a
        line coming back is its echo. The value is the manual's default (Table 3-7) or
        the cell's; every action sends its own repetitions anyway. Anything else that
        comes is kept in ``probe`` (escaped) for the commissioning report, not judged."""
        value = self.spec.repetitions.feed_forward or 3
        self._write(set_line(self.spec.commands.feed_forward, value))
        self.probe, self.echo = [], False
        end = time.monotonic() + self.spec.echo_probe_s
        quiet_since = time.monotonic()
        give_up = end + self.spec.timeout_s            # a chattering line ends it too
        while (time.monotonic() < end or time.monotonic() - quiet_since < self.spec.quiet_s) \
                and time.monotonic() < give_up:
            for text in self._lines():
                quiet_since = time.monotonic()
                if text == self._sent:
                    self.echo = True
                else:
                    self.probe.append(shown(text))
            if self.echo and time.monotonic() - quiet_since >= self.spec.quiet_s:
                break

    def _drop(self, why: str) -> CommsLost:
        if self._ser is not None:
            try:
                self._ser.close()
            except Exception:                 # noqa: BLE001
                pass
        self._ser = None
        self._buf, self._owed, self._carry = b"", {}, []
        return CommsLost(f"AnyFeeder at {self.spec.url}: {why}")

    def _write(self, line: bytes) -> None:
        assert self._ser is not None
        try:
            self._ser.write(line)
        except (serial.SerialException, OSError) as e:
            raise self._drop(f"write failed: {e}") from e
        self._sent = line.decode("ascii").strip()
        self._recent.append(self._sent)
        self._unacked = set()
        self.log.append("> " + self._sent)

    def _lines(self) -> list[str]:
        """Lines read and not yet judged (left over from the last exchange first), or
        what one read brings (a CR LF feeder's LF stripped)."""
        if self._carry:
            out, self._carry = self._carry, []
            return out
        assert self._ser is not None
        try:
            chunk = self._ser.read(64)
        except (serial.SerialException, OSError) as e:
            raise self._drop(f"read failed: {e}") from e
        if chunk:
            self._last_rx = time.monotonic()
        self._buf += chunk
        out = []
        while CR in self._buf:
            raw, self._buf = self._buf.split(CR, 1)
            text = raw.decode("latin-1").strip()
            if text:
                self.log.append("< " + text)
                out.append(text)
        if len(self._buf) > LINE_CAP:
            raise self._drop(f"{LINE_CAP} bytes without <cr>: {shown(self._buf)}")
        return out

    def _reply(self, text: str) -> Reply | None:
        """A motor code; None for the echo of the last line; a link drop for anything
        else (never credited to an action)."""
        if text in self._recent and not is_reply(text):
            self.echo = True
            return None
        try:
            return parse_reply(text)
        except ProtocolError as e:
            raise self._drop(str(e)) from e

    def _drain(self, name: str, after: str = "the last command", sending: bool = True
               ) -> list[str]:
        """Read until the line has been quiet for ``quiet_s`` and the motors still busy
        with an earlier action have reported: their codes and any late one belong to
        that action, never to the next. A late error is raised naming the action it came
        after (``sending``: and ``name`` is not written)."""
        seen: list[str] = []
        late: list[str] = []
        deadline = time.monotonic() + self.spec.timeout_s
        first = True
        while True:
            now = time.monotonic()
            if self._owed and now > deadline:
                busy = ", ".join(f"motor {m} ({a})" for m, a in sorted(self._owed.items()))
                raise PlateFault(f"AnyFeeder {name}: still busy after "
                                 f"{self.spec.timeout_s:g} s: {busy}")
            if not first and not self._owed and not self._carry \
                    and now - self._last_rx >= self.spec.quiet_s:
                break
            first = False
            for text in self._lines():
                reply = self._reply(text)
                if reply is None:
                    continue
                seen.append(reply.text)
                if reply.code == BUSY:
                    if reply.motor in self._unacked:     # its busy after its done (the
                        self._unacked.discard(reply.motor)   # order of
                        continue                         # anyfeeder_connector's mock)
                    self._owed.setdefault(reply.motor, after)    # busy again: owed
                    continue
                was = self._owed.pop(reply.motor, None)
                if reply.code != DONE:
                    late.append(f"{reply.describe()} (after {was or after})")
        if late:
            head = f"AnyFeeder {name}: not sent: late " if sending else \
                f"AnyFeeder {name}: late "
            raise PlateFault(head + "; ".join(late))
        return seen

    # ------------------------------------------------------------------ an exchange
    def _exchange(self, name: str, line: bytes, duration: float,
                  cancel: threading.Event) -> list[str]:
        """Write ``line`` once the line is quiet, then read until both motors have
        reported; the codes seen."""
        self._port()
        self._drain(name)
        if cancel.is_set():
            raise JobCancelled(f"{name} cancelled")
        self._write(line)
        deadline = time.monotonic() + duration + self.spec.timeout_s
        busy: set[int] = set()
        ended: set[int] = set()
        errors: list[Reply] = []
        codes: list[str] = []
        stopped = False
        while True:
            if cancel.is_set() and not stopped:
                stopped = True
                self._write(command_line(self.spec.commands.stop))
                deadline = time.monotonic() + self.spec.timeout_s
            if time.monotonic() > deadline:
                if errors:
                    self._owed = {m: name for m in busy - ended}
                    break
                self._judge_silence(name, duration)
                self._owed = {m: name for m in busy - ended}
                raise PlateFault(f"AnyFeeder {name}: no completion in "
                                 f"{duration + self.spec.timeout_s:g} s (motors done: "
                                 f"{sorted(ended) or 'none'})")
            lines = self._lines()
            while lines and not ended >= MOTORS:
                reply = self._reply(lines.pop(0))
                if reply is None:
                    continue
                codes.append(reply.text)
                if reply.code == BUSY:
                    busy.add(reply.motor)
                    continue
                ended.add(reply.motor)
                if reply.code != DONE:
                    errors.append(reply)
            self._carry = lines + self._carry      # after both motors: the linger's
            if ended >= MOTORS:
                break
            # after an error a motor that never said busy may say nothing more
            if errors and not (busy - ended) and \
                    time.monotonic() - self._last_rx >= self.spec.quiet_s:
                break
        self._owed = {m: name for m in busy - ended}
        self._unacked = ended - busy
        if errors:
            raise PlateFault(f"AnyFeeder {name}: " + "; ".join(r.describe() for r in errors))
        # linger until quiet: a code after both motors' (a late m28) is this action's
        codes += self._drain(name, after=name, sending=False)
        if stopped:
            raise JobCancelled(f"{name} cancelled (stopped: x={self.spec.commands.stop})")
        return codes

    def _judge_silence(self, name: str, duration: float) -> None:
        """An action's end did not come: a dead line, an end lost on the line, or a stuck
        feeder. Ask with the stop command, harmless on an idle feeder: nothing back is a
        dead line (a pulled cable, the feeder off: the port is opened afresh and owes
        nothing); both motors done is an idle feeder whose end of ``name`` the line lost
        (a lost link, not a plate fault). Any other answer returns: the feeder is stuck."""
        self._write(command_line(self.spec.commands.stop))
        end = time.monotonic() + min(self.spec.timeout_s, 2.0)
        done: set[int] = set()
        heard = False
        while time.monotonic() < end and not done >= MOTORS:
            for text in self._lines():
                reply = self._reply(text)
                if reply is None:
                    continue
                heard = True
                if reply.code == DONE:
                    done.add(reply.motor)
                elif reply.code != BUSY:       # a standard response: busy, then done
                    return
        if not heard:
            raise self._drop(f"nothing came back in {duration + self.spec.timeout_s:g} s "
                             f"after {name}, nor to a stop: the line is down or the "
                             "feeder off")
        if done >= MOTORS:
            self._owed = {}
            raise CommsLost(f"AnyFeeder at {self.spec.url}: the end of {name} was lost on "
                            "the line; the feeder answers idle")

    def _write_params(self) -> None:
        """The cell's speeds (``ab[N+16]=V x=N+16``, a standard response) and repetitions
        (``ab[N]=V``, no response), written after each init; ``params`` keeps each with
        what the feeder answered (the commissioning's read-back)."""
        c = self.spec.commands
        never = threading.Event()
        for field in dataclasses.fields(self.spec.speeds):
            value = getattr(self.spec.speeds, field.name)
            if value is None:
                continue
            param = getattr(c, field.name) + SPEED_OFFSET
            codes = self._exchange(f"plate.speed.{field.name}",
                                   command_line(param, value), 0.0, never)
            self.params[f"ab[{param}]"] = {"what": f"{field.name} speed", "value": value,
                                           "answer": codes}
        for field in dataclasses.fields(self.spec.repetitions):
            value = getattr(self.spec.repetitions, field.name)
            if value is None:
                continue
            param = getattr(c, field.name)
            what = f"plate.repetitions.{field.name}"
            self._drain(what)
            self._write(set_line(param, value))
            answer = self._drain(what, after=f"ab[{param}]={value}")
            self.params[f"ab[{param}]"] = {"what": f"{field.name} repetitions",
                                           "value": value, "answer": answer}
