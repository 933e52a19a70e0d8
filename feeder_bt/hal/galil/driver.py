"""The Galil controller over pyserial: one link, one reader, one device worker.

``serial_for_url`` opens either a serial port (``/dev/ttyS0``, a pty) or a TCP connection
(``socket://host:23``) with the same code. Threads, and why:

- the *reader* does blocking ``read(1)`` with a short timeout and feeds a
  ``ReplySplitter`` (``in_waiting`` is wrong for ``socket://``, so it is never used):
  replies go to a queue for the worker, unsolicited lines become events at once;
- the *device worker* (one thread, the thesis's monitor) sends one command at a time and
  waits for its reply, so commands are never interleaved. ``command()`` queues a command
  and returns a ``Future``; ``ask()`` is the same, synchronously, for code already on the
  worker;
- a *scheduler* re-queues multi-step operations (wait for ``_BGB`` to read 0, then read
  the position) so that the worker never blocks for longer than one command.

A rejected command (``?``) is followed by ``TC1`` and raises ``GalilError(code, text)``.
A dropped link, or no reply within ``spec.timeout_s``, raises ``CommsLost`` for the
command in flight and closes the link; the next command reconnects, after a back-off
(0.1 s doubling to 2 s) once an attempt has failed. Every connect re-runs the start-up
sequence (docs/real-cell.md has the source of each step):

1. ``EO 0`` first (a serial port echoes until then), then ``CW 1``;
2. ``WH``: which Ethernet handle we are; ``CF`` that handle, so program messages come to
   us; ``IH h=>-2`` frees the handles of our earlier, dropped connections (``free_handles``);
3. ``HXn`` of *our* threads only (a program on another thread is never killed: the
   connect fails with a clear error instead, as ``DL`` would be refused);
4. the safety settings of the cell file on our axes: ``ER`` (``error_limit_mm`` in
   counts), ``TL`` and ``TK 0``, ``OE``, ``CN`` (limit switch and latch polarity);
5. ``DL`` of ``spec.programs``, program variables, ``XQ`` of the input monitor (0), the
   distance notifier (1) and the host watchdog (2);
6. no ``SH`` unless ``spec.servo_on`` says so (default ``never``: the first ``SH`` of a
   session is a person's, ``servo(True)`` from the operator's Start or Reset or from
   commissioning; a motor that is off stays off);
7. initial reads.

A *health poll* (every ``HEALTH_S``) pets the card's watchdog, re-asserts ``CF``, reads
``_XQ0``-``_XQ2`` and the input monitor's heartbeat ``INBEAT``, and every third poll each
axis's ``_MO``, ``_SC``, ``_TE``, ``_LF``, ``_LR`` into ``status(axis)``. A dead thread is
started again; one that cannot be (``XQ`` refused, or dead again and again) or a heartbeat
that stopped is a *card fault*: the belts are stopped (``ST`` of our axes) and every
conveyor's ``fault()`` says so until an operator's reset.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import serial

from feeder_bt.core.clock import Clock, sampled_at
from feeder_bt.core.encoder import wrap
from feeder_bt.core.errors import CommsLost, ConfigError, ConveyorFault, HalError
from feeder_bt.core.model import GalilSpec
from feeder_bt.hal.galil.link import (
    DEAD,
    Connection,
    Scheduler,
    done,
    failed,
    retrieve,
    set_exception,
    set_result,
)
from feeder_bt.hal.galil.protocol import (
    AXES,
    CardEvent,
    DistanceEvent,
    Event,
    GalilError,
    InputsEvent,
    ProgramError,
    ProgramLine,
    Reply,
    download_payload,
    parse_int,
    parse_tell_code,
    parse_unsolicited,
    read_programs,
    stop_text,
)
from feeder_bt.hal.galil.startup import (
    DIST_NOTIFIER,
    HEALTH_S,
    INPUT_MONITOR,
    WATCHDOG,
    AxisStatus,
    CardSetup,
)

log = logging.getLogger(__name__)

PROGRAMS_DIR = Path(__file__).resolve().parents[3] / "galil_programs"
READ_TIMEOUT_S = 0.05           # reader's read(1) timeout: how fast it notices a close
BACKOFF_FIRST_S = 0.1
BACKOFF_MAX_S = 2.0
POLL_S = 0.05                   # status polls of multi-step operations: 20 Hz
POSITION_POLL_S = 0.1           # TP refreshes: at most 10 Hz per axis
COUNTER_BITS = 32

EventCallback = Callable[[Event, float], None]


class Retry:
    """Returned by a step: run me again after ``POLL_S``."""


RETRY = Retry()


@dataclass(frozen=True)
class Delay:
    """Returned by a step: go on to the next step after ``seconds``."""

    seconds: float


class GalilController(CardSetup):
    """A Galil DMC on ``spec.url``: commands, events, positions and inputs.

    ``counts_per_mm`` (the cell's ``encoder``) turns ``spec.notify_mm`` into the
    notifier's step in counts. ``servo_axes`` (by default the axes of ``spec.axes``) are
    switched on (``SH``) only by ``servo(True)`` (a person's action), unless
    ``spec.servo_on`` allows it at connect.
    Construction prepares the programs (so a bad program fails at once, naming
    ``file:line``, before anything is sent) and starts connecting in the background;
    ``ready`` is that first connect's ``Future``.
    """

    def __init__(self, spec: GalilSpec, clock: Clock, programs_dir: Path | str = PROGRAMS_DIR,
                 counts_per_mm: float = 20.0, servo_axes: str | None = None,
                 connect: bool = True) -> None:
        self.spec, self.clock = spec, clock
        self.cpm = float(counts_per_mm)
        self.programs_dir = Path(programs_dir)
        self.notify_axis = spec.latch_axis.upper()
        bad = [a for a in (self.notify_axis, *spec.axes.values()) if a.upper() not in AXES]
        if bad or len(self.notify_axis) != 1:
            raise ConfigError(f"Galil axes must be one letter of {AXES}, "
                              f"got {bad or [self.notify_axis]}", key="galil")
        self.servo_axes = servo_axes if servo_axes is not None else "".join(
            sorted({a.upper() for a in spec.axes.values()}))
        self.program: list[ProgramLine] = read_programs(self.programs_dir, spec.programs)
        labels = {pl.text.split(";", 1)[0].strip().upper()
                  for pl in self.program if pl.text.startswith("#")}
        self._has_monitor = INPUT_MONITOR in labels
        self._has_notifier = DIST_NOTIFIER in labels and spec.notify_mm > 0
        self._worker_name = f"galil-worker-{id(self):x}"
        self._worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix=self._worker_name)
        self._sched = Scheduler()
        self._conn: Connection | None = None
        self._backoff = BACKOFF_FIRST_S
        self._next_attempt = 0.0
        self._last_error: BaseException | None = None
        self._lock = threading.Lock()
        self._positions: dict[str, tuple[int, float]] = {}       # axis -> (count, clock t)
        self._rtts: dict[str, float] = {}        # axis -> the latest TP's round trip (s)
        self._polled: dict[str, float] = {}                      # axis -> monotonic of last TP
        self._polling: set[str] = set()
        self._subscribers: list[EventCallback] = []
        self._connect_hooks: list[Callable[[], None]] = []
        self.inputs_mask: int | None = None
        self.outputs_mask: int | None = None
        self.connects = 0                   # successful connects (reconnects = connects - 1)
        self.program_errors: list[str] = []
        self.card_events: list[tuple[str, str, float]] = []    # (kind, detail, t)
        # belts found stopped after a reconnect, by the card's watchdog (counted once per
        # outage) or otherwise: (conveyor, why, clock t)
        self.watchdog_stops = 0
        self.stopped_while_away: list[tuple[str, str, float]] = []
        self._dog_counted = -1              # the connect whose watchdog stop was counted
        self.handle: str | None = None      # our Ethernet handle letter (WH), None on serial
        self._held_handles: set[str] = set()
        self.firmware: str | None = None    # the card's answer to ^R^V / CW (commissioning)
        self._has_watchdog = WATCHDOG in labels and spec.watchdog_s > 0
        self._status: dict[str, AxisStatus] = {}
        self.thread_lines: dict[int, int] = {}
        self.restarts: dict[int, int] = {}
        self._deaths: dict[int, list[float]] = {}   # thread -> clock times it was found dead
        self._beat: tuple[int, float] | None = None  # (INBEAT, clock time it last moved)
        self.card_fault: str | None = None  # a dead thread or heartbeat: belts stopped
        self.servo_refused: str | None = None   # why the start-up SH was not sent or failed
        self._health_busy = False
        self._closed = False
        self.ready: Future = self.submit(self._first_connect) if connect else done(False)
        self.ready.add_done_callback(retrieve)
        if connect:
            self._sched.call_later(HEALTH_S, self._health_tick)

    # ================================================================ public API
    def command(self, text: str) -> Future:
        """Queue one command for the worker; the future's result is the reply data."""
        return self.submit(self.ask, text)

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """Run ``fn`` on the device worker (where it may call ``ask``)."""
        if self._closed:
            return failed(CommsLost("Galil controller closed"))
        try:
            return self._worker.submit(fn, *args)
        except RuntimeError:
            return failed(CommsLost("Galil controller closed"))

    def ask(self, text: str) -> str:
        """Send one command and wait for its reply (device worker only).

        Raises ``GalilError`` (with ``TC1``'s code and text) when rejected, ``CommsLost``
        when the link drops or the reply does not come within ``spec.timeout_s``.
        """
        if not threading.current_thread().name.startswith(self._worker_name):
            raise HalError("GalilController.ask() runs on the device worker only; "
                           "use command() or submit()")
        conn = self._ensure_connected()
        return self._ask_on(conn, text)

    def ask_number(self, text: str) -> int:
        return parse_int(self.ask(text))

    def subscribe(self, fn: EventCallback) -> Callable[[], None]:
        """Call ``fn(event, t)`` for every unsolicited event (on the reader thread)."""
        with self._lock:
            self._subscribers.append(fn)

        def unsubscribe() -> None:
            with self._lock:
                if fn in self._subscribers:
                    self._subscribers.remove(fn)
        return unsubscribe

    def events(self) -> queue.Queue:
        """A queue receiving ``(event, t)`` for every unsolicited event from now on."""
        q: queue.Queue = queue.Queue()
        self.subscribe(lambda ev, t: q.put((ev, t)))
        return q

    def on_connect(self, fn: Callable[[], None]) -> None:
        """Run ``fn`` on the worker after every connect (settings the card must be told)."""
        self._connect_hooks.append(fn)
        if self._conn is not None and self._conn.alive:
            self.submit(fn).add_done_callback(retrieve)

    def note_stop_while_away(self, conveyor: str, stop_code: int) -> None:
        """A conveyor found stopped after a reconnect (its ``_SC``): stop code 4 (ST) is
        the card's watchdog, which stops every axis of ours at once: one stop per outage."""
        why = "the card's watchdog (ST)" if stop_code == 4 else stop_text(stop_code)
        self.stopped_while_away.append((conveyor, why, self.clock.now()))
        if stop_code == 4 and self._dog_counted != self.connects:
            self._dog_counted = self.connects
            self.watchdog_stops += 1
        log.warning("Galil at %s: %s found stopped after the reconnect: %s", self.spec.url,
                    conveyor, why)

    def status(self, axis: str) -> AxisStatus | None:
        """The axis as the health poll last read it (None before the first read)."""
        with self._lock:
            return self._status.get(axis.upper())

    @property
    def connected(self) -> bool:
        return self._conn is not None and self._conn.alive

    def position(self, axis: str) -> int | None:
        """Latest known count of ``axis`` (distance events and TP reads), or None."""
        with self._lock:
            got = self._positions.get(axis.upper())
        return None if got is None else got[0]

    def position_age(self, axis: str) -> float | None:
        """Clock seconds since the latest count of ``axis`` was read."""
        with self._lock:
            got = self._positions.get(axis.upper())
        return None if got is None else self.clock.now() - got[1]

    def position_rtt(self, axis: str) -> float:
        """The round trip of the read behind ``position(axis)``: when the card sampled the
        count is known to half of it (0: a notification, or never read)."""
        with self._lock:
            return self._rtts.get(axis.upper(), 0.0)

    def refresh_position(self, axis: str, max_age: float = POSITION_POLL_S) -> None:
        """Queue a ``TP`` read of ``axis`` unless one ran in the last ``max_age`` s."""
        axis = axis.upper()
        now = time.monotonic()
        with self._lock:
            if axis in self._polling or now - self._polled.get(axis, -1e9) < max_age:
                return
            self._polling.add(axis)
            self._polled[axis] = now

        def done(f: Future) -> None:
            with self._lock:
                self._polling.discard(axis)
            retrieve(f)
        self.submit(self.read_position, axis).add_done_callback(done)

    def read_position(self, axis: str) -> int:
        """``TP`` now (device worker only); updates the latest count, stamped at the
        round trip's middle (``sampled_at``)."""
        t0 = self.clock.now()
        count = parse_int(self.ask(f"TP{axis.upper()}"))
        t1 = self.clock.now()
        self._set_position(axis.upper(), count, sampled_at(t0, t1))
        with self._lock:
            self._rtts[axis.upper()] = t1 - t0
        return count

    def run_steps(self, name: str, steps: list[Callable[[], Any]],
                  timeout_s: float | None = None,
                  on_timeout: Callable[[], HalError] | None = None) -> Future:
        """Run ``steps`` in order on the worker without ever blocking it.

        A step returns ``RETRY`` (run it again after ``POLL_S``), ``Delay(s)`` (go on after
        ``s``), None or a value (go on at once; the last value is the result). Past
        ``timeout_s`` a retrying step fails with ``on_timeout()`` (default ``ConveyorFault``).
        Cancelling the future stops the sequence at the next step.
        """
        fut: Future = Future()
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        state: dict[str, Any] = {"i": 0, "result": None}

        def resume() -> None:
            if fut.done():
                return
            if self._closed:
                set_exception(fut, CommsLost("Galil controller closed"))
                return
            self.submit(run).add_done_callback(retrieve)

        def run() -> None:
            if fut.done():
                return
            try:
                while state["i"] < len(steps):
                    r = steps[state["i"]]()
                    if isinstance(r, Retry):
                        if deadline is not None and time.monotonic() > deadline:
                            raise (on_timeout() if on_timeout else
                                   ConveyorFault(f"{name}: not done within {timeout_s:.1f} s"))
                        self._sched.call_later(POLL_S, resume)
                        return
                    state["i"] += 1
                    if isinstance(r, Delay):
                        self._sched.call_later(r.seconds, resume)
                        return
                    if r is not None:
                        state["result"] = r
                set_result(fut, state["result"])
            except BaseException as e:            # noqa: BLE001 - delivered through the future
                set_exception(fut, e)

        if self._closed:
            set_exception(fut, CommsLost("Galil controller closed"))
        else:
            self.submit(run).add_done_callback(retrieve)
        return fut

    def close(self) -> None:
        """Stop the worker, the scheduler and the reader; close the link."""
        if self._closed:
            return
        self._closed = True
        self._sched.close()
        conn = self._conn
        if conn is not None:
            conn.close()                     # a command waiting for a reply ends now
        self._worker.shutdown(wait=True, cancel_futures=True)
        conn, self._conn = self._conn, None
        if conn is not None:
            conn.close()

    # ================================================================ connection
    def _first_connect(self) -> bool:
        self._ensure_connected()
        return True

    def _ensure_connected(self) -> Connection:
        conn = self._conn
        if conn is not None and conn.alive:
            return conn
        if conn is not None:
            self._last_error = conn.error or self._last_error
            conn.close()
            self._conn = None
        if self._closed:
            raise CommsLost("Galil controller closed")
        now = time.monotonic()
        if now < self._next_attempt:
            raise CommsLost(f"Galil at {self.spec.url} not connected (next attempt in "
                            f"{self._next_attempt - now:.2f} s; last error: {self._last_error})")
        try:
            conn = self._connect()
        except HalError as e:
            self._last_error = e
            self._next_attempt = time.monotonic() + self._backoff
            self._backoff = min(BACKOFF_MAX_S, self._backoff * 2)
            if isinstance(e, CommsLost):
                raise
            raise CommsLost(f"Galil at {self.spec.url}: connect failed: {e}") from e
        self._backoff = BACKOFF_FIRST_S
        self._next_attempt = 0.0
        return conn

    def _connect(self) -> Connection:
        try:
            ser = serial.serial_for_url(self.spec.url, baudrate=self.spec.baud,
                                        timeout=READ_TIMEOUT_S, rtscts=self.spec.rtscts,
                                        write_timeout=self.spec.timeout_s)
        except (serial.SerialException, OSError, ValueError) as e:
            raise CommsLost(f"Galil at {self.spec.url}: cannot open: {e}") from None
        conn = Connection(ser, self._on_line, self.spec.url)
        self._conn = conn
        first = self.connects == 0
        try:
            self._ask_on(conn, "EO 0")            # no echo first: a serial port echoes
            self._ask_on(conn, "CW 1")            # unsolicited bytes with the top bit set
            self._claim_handle(conn)
            self._halt_our_threads(conn)          # DL is refused while a program runs
            self._send_safety(conn)               # ER, TL, TK, OE, CN before anything moves
            self._ask_on(conn, "DL", payload=download_payload(self.program))
            self._set_program_variables(conn)
            if self._has_monitor:
                self._ask_on(conn, f"XQ {INPUT_MONITOR},0")
            if self._has_notifier:
                self._ask_on(conn, f"XQ {DIST_NOTIFIER},1")
            if self._has_watchdog:
                self._ask_on(conn, f"XQ {WATCHDOG},2")
            self._servo_at_connect(conn, first)
            self.inputs_mask = self._read_inputs(conn)
            self.outputs_mask = parse_int(self._ask_on(conn, "MG _OP0"))
            for axis in self.servo_axes:
                self._set_position(axis, parse_int(self._ask_on(conn, f"TP{axis}")))
            self._beat = None                     # the heartbeat is timed afresh
            for hook in list(self._connect_hooks):
                hook()
        except BaseException:
            if self._conn is conn:
                self._conn = None
            conn.close()
            raise
        self.connects += 1
        log.info("Galil at %s connected (%d)", self.spec.url, self.connects)
        return conn

    def _drop(self, conn: Connection, why: str) -> CommsLost:
        if self._conn is conn:
            self._conn = None
        conn.close()
        self._last_error = CommsLost(why)
        return CommsLost(why)

    def _ask_on(self, conn: Connection, text: str, payload: bytes | None = None) -> str:
        try:
            data = text.encode("ascii") + b"\r" + (payload or b"")
        except UnicodeEncodeError:
            raise GalilError(1, "not ASCII", command=text) from None
        while True:                                  # a stale reply must not answer us
            try:
                stale = conn.replies.get_nowait()
            except queue.Empty:
                break
            if stale is DEAD:
                raise self._drop(conn, f"Galil link lost before {text!r}: {conn.error}")
        if not conn.alive:
            raise self._drop(conn, f"Galil link lost before {text!r}: {conn.error}")
        try:
            conn.ser.write(data)
        except Exception as e:                       # noqa: BLE001 - any write failure
            raise self._drop(conn, f"Galil link lost sending {text!r}: {e}") from None
        reply = self._wait_reply(conn, text)
        if reply.ok:
            return reply.data
        try:
            conn.ser.write(b"TC1\r")
        except Exception as e:                       # noqa: BLE001
            raise self._drop(conn, f"Galil link lost sending TC1: {e}") from None
        tc = self._wait_reply(conn, "TC1")
        code, why = parse_tell_code(tc.data) if tc.ok else (-1, "unknown (TC1 rejected)")
        raise GalilError(code, why, command=text)

    def _wait_reply(self, conn: Connection, text: str) -> Reply:
        try:
            item = conn.replies.get(timeout=self.spec.timeout_s)
        except queue.Empty:
            raise self._drop(conn, f"Galil: no reply to {text!r} within "
                                   f"{self.spec.timeout_s:g} s") from None
        if item is DEAD:
            raise self._drop(conn, f"Galil link lost waiting for {text!r}: {conn.error}")
        return item

    # ================================================================ events
    def _on_line(self, line: str) -> None:
        ev = parse_unsolicited(line)
        t = self.clock.now()
        if isinstance(ev, InputsEvent):
            self.inputs_mask = ev.mask
        elif isinstance(ev, DistanceEvent):
            self._set_position(self.notify_axis, ev.count, t)
        elif isinstance(ev, ProgramError):
            self.program_errors.append(ev.text)
            log.warning("Galil program error: %s", ev.text)
        elif isinstance(ev, CardEvent):
            self.card_events.append((ev.kind, ev.detail, t))
            log.warning("Galil card event: %s %s", ev.kind, ev.detail)
        with self._lock:
            subscribers = list(self._subscribers)
        for fn in subscribers:
            try:
                fn(ev, t)
            except Exception:                        # noqa: BLE001
                log.exception("Galil event subscriber failed")

    def _set_position(self, axis: str, count: int, t: float | None = None) -> None:
        with self._lock:
            self._positions[axis] = (wrap(int(count), COUNTER_BITS),
                                     self.clock.now() if t is None else t)
