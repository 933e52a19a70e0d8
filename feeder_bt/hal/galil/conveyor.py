"""HAL devices on a Galil controller: a conveyor axis (``Conveyor``) and digital I/O.

Millimetres and mm/s at the HAL, encoder counts on the wire (``counts_per_mm`` of the
cell's ``encoder``). Every method returns at once: a command becomes a ``FutureJob`` on
the controller's device worker; an operation of several commands (stop, then wait for
``_BGB`` to read 0, then read the position) is a step sequence the worker runs a command
at a time; a belt-distance notification is a ``Job`` whose ``poll()`` compares counts.
"""

from __future__ import annotations

import threading
from typing import Any

from feeder_bt.core.clock import Clock
from feeder_bt.core.encoder import diff
from feeder_bt.core.errors import CardFault, CommsLost, ConveyorFault, HalError
from feeder_bt.core.jobs import DoneJob, FutureJob, Job, JobState
from feeder_bt.core.model import IoSignal
from feeder_bt.hal.galil.driver import RETRY, Delay, GalilController
from feeder_bt.hal.galil.protocol import (
    DistanceEvent,
    Event,
    GalilError,
    InputsEvent,
    explicit,
    parse_int,
    positional,
    stop_text,
)
from feeder_bt.hal.interfaces import IoChange, speed_refused, watchdog_stopped

COUNTER_BITS = 32
FRESH_S = 0.5                # a count older than this tells nothing of a stall
STALL_S = 2.0                # jogging with no encoder motion this long: a stall
SETTLE_MARGIN_S = 3.0        # slack on top of a motion's planned time before it is a fault
# _SC stop codes (Galil command reference, SC; the emulator uses the same; docs/real-cell.md)
class GalilConveyor:
    """One conveyor on one Galil axis, implementing ``hal.interfaces.Conveyor``."""

    def __init__(self, controller: GalilController, name: str, axis: str,
                 counts_per_mm: float | None = None, max_mm_s: float = 400.0,
                 accel_mm_s2: float = 1500.0, clock: Clock | None = None,
                 cell_file: object = None) -> None:
        self.ctl = controller
        self.name = name
        self.axis = axis.upper()
        self.cpm = float(counts_per_mm if counts_per_mm is not None else controller.cpm)
        self.max_mm_s = float(max_mm_s)
        self.accel = float(accel_mm_s2)
        self.cell_file = cell_file     # named when a speed above max_mm_s is refused
        self.clock = clock or controller.clock
        self._commanded = 0.0          # mm/s, what we last asked for (speed())
        self._mode = "idle"            # idle | jog | move: what the axis is doing for us
        self._stall_ref: tuple[float, int] | None = None   # (since, count) for fault()
        self._stall_counts = max(1, round(controller.spec.stall_mm * self.cpm))
        self._commanded_at = 0.0       # clock time of our last motion command
        controller.on_connect(self._configure)
        controller.on_connect(self._resume)

    # ---------------------------------------------------------------- helpers
    def _counts(self, mm: float) -> int:
        return int(round(mm * self.cpm))

    def _configure(self) -> None:
        """Acceleration and deceleration of the axis (re-sent after every connect)."""
        a = self._counts(self.accel)
        self.ctl.ask(positional("AC", {self.axis: a}))
        self.ctl.ask(positional("DC", {self.axis: a}))

    def _resume(self) -> None:
        """After a reconnect: a belt we were running that stands still was stopped while
        the link was down (the card's watchdog, by ST: stop code 4), and the card's message
        saying so was lost with the link. Note why, and jog again at the speed we had, as
        the simulated cell does; a motor found off stays off (an operator matter, said by
        ``fault()``), and nothing moves after a card fault."""
        if self.ctl.connects == 0 or self._mode != "jog" or abs(self._commanded) < 1.0:
            return
        if self._running():
            return
        code = parse_int(self.ctl.ask(f"MG _SC{self.axis}"))
        self.ctl.note_stop_while_away(self.name, code)
        if self.ctl.card_fault is not None or parse_int(self.ctl.ask(f"MG _MO{self.axis}")):
            return
        self.ctl.ask(positional("JG", {self.axis: self._counts(self._commanded)}))
        self.ctl.ask(f"BG{self.axis}")
        self._commanded_at = self.clock.now()
        self._stall_ref = None

    def _running(self) -> bool:
        """``_BGx``: 1 while the axis's profiler runs (device worker only)."""
        return parse_int(self.ctl.ask(f"MG _BG{self.axis}")) != 0

    def _job(self, name: str, future) -> Job:
        return FutureJob(f"{self.name}.{name}", future, self.clock)

    def _ensure_idle(self, state: dict[str, Any]):
        """Step: stop the axis if it moves and wait until it has stopped."""
        def step():
            if not self._running():
                return None
            if not state.get("stop_sent"):
                self.ctl.ask(f"ST{self.axis}")
                state["stop_sent"] = True
            return RETRY
        return step

    def _wait_idle(self):
        return lambda: RETRY if self._running() else None

    def _read_position(self):
        def step():
            self.ctl.read_position(self.axis)
            return self.clock.now()
        return step

    def _start_move(self, counts: int, speed_counts: int):
        def step():
            self.ctl.ask(explicit("SP", self.axis, speed_counts))
            self.ctl.ask(positional("PR", {self.axis: counts}))
            self._begin()
            self._mode = "move"
        return step

    def _start_jog(self, mm_s: float, state: dict[str, Any]):
        """Step: jog at ``mm_s``; a new JG while jogging just changes speed."""
        def step():
            running = self._running()
            if running and self._mode != "jog":
                if not state.get("stop_sent"):
                    self.ctl.ask(f"ST{self.axis}")
                    state["stop_sent"] = True
                return RETRY                      # a position move must end before JG
            before = state.get("from_mm_s", 0.0) if running else 0.0
            self.ctl.ask(positional("JG", {self.axis: self._counts(mm_s)}))
            if not running:
                self._begin()
            self._mode = "jog"
            return Delay(abs(mm_s - before) / self.accel)   # until the speed is reached
        return step

    def _begin(self) -> None:
        """``BG``; a motor that is off is an operator matter, said so (not a bare code 20).
        After a card fault nothing moves until an operator's reset."""
        if self.ctl.card_fault is not None:
            raise self._card_fault()
        try:
            self.ctl.ask(f"BG{self.axis}")
        except GalilError as e:
            if e.code != 20:
                raise
            raise ConveyorFault(f"{self.name}: motor off on Galil axis {self.axis} (turned "
                                f"off by an off-on-error, the e-stop or an operator): it "
                                f"stays off until an operator's reset turns it on") from None
        self._commanded_at = self.clock.now()

    def _move_time(self, distance_mm: float, mm_s: float) -> float:
        v = max(1e-6, min(abs(mm_s), self.max_mm_s))
        return abs(distance_mm) / v + 2 * v / self.accel + SETTLE_MARGIN_S

    # ---------------------------------------------------------------- Conveyor
    def set_speed(self, mm_s: float) -> Job:
        """Jog at ``mm_s`` (``JG`` + ``BG``; 0 stops); ends when the speed is reached. Above
        the cell's ``max_mm_s`` the job fails and nothing is sent (never a silent clamp)."""
        refused = speed_refused(self.name, "set_speed", mm_s, self.max_mm_s, self.cell_file)
        if refused is not None:
            return refused
        mm_s = max(-self.max_mm_s, min(self.max_mm_s, float(mm_s)))   # the 1e-9 tolerance
        if self._counts(mm_s) == 0:
            return self._stop("set_speed")
        state: dict[str, Any] = {"from_mm_s": self._commanded}
        self._commanded = mm_s
        fut = self.ctl.run_steps(f"{self.name}.set_speed", [self._start_jog(mm_s, state)],
                                 timeout_s=self._move_time(0, self.max_mm_s))
        return self._job("set_speed", fut)

    def move(self, distance_mm: float, mm_s: float) -> Job:
        """Relative move (``SP``, ``PR``, ``BG``); ends when ``_BGx`` reads 0. Above the
        cell's ``max_mm_s`` the job fails and nothing is sent."""
        refused = speed_refused(self.name, "move", mm_s, self.max_mm_s, self.cell_file)
        if refused is not None:
            return refused
        counts = self._counts(distance_mm)
        speed = self._counts(min(abs(mm_s), self.max_mm_s))
        if speed <= 0:
            return DoneJob(f"{self.name}.move", error=HalError(f"{self.name}: move at "
                                                              f"{mm_s} mm/s"))
        self._commanded = 0.0
        state: dict[str, Any] = {}
        steps = [self._ensure_idle(state), self._start_move(counts, speed), self._wait_idle(),
                 self._read_position()]
        fut = self.ctl.run_steps(f"{self.name}.move", steps,
                                 timeout_s=self._move_time(distance_mm, mm_s)
                                 + self._move_time(0, self.max_mm_s))
        return self._job("move", fut)

    def stop(self) -> Job:
        """``ST``; ends when the axis has stopped (``_BGx`` reads 0)."""
        return self._stop("stop")

    def _stop(self, name: str) -> Job:
        self._commanded = 0.0

        def send():
            self.ctl.ask(f"ST{self.axis}")
            self._mode = "idle"
        steps = [send, self._wait_idle(), self._read_position()]
        fut = self.ctl.run_steps(f"{self.name}.{name}", steps,
                                 timeout_s=self._move_time(0, self.max_mm_s))
        return self._job(name, fut)

    def shake(self, amplitude_mm: float, cycles: int) -> Job:
        """Back-and-forth moves at full speed, then back to the speed it had."""
        before = self._commanded
        a = self._counts(amplitude_mm)
        v = self._counts(self.max_mm_s)
        state: dict[str, Any] = {}
        steps = [self._ensure_idle(state)]
        for _ in range(max(1, int(cycles))):
            steps += [self._start_move(a, v), self._wait_idle(),
                      self._start_move(-a, v), self._wait_idle()]
        if self._counts(before):
            steps.append(self._start_jog(before, {"from_mm_s": 0.0}))
        steps.append(self._read_position())
        total = max(1, int(cycles)) * 2 * self._move_time(amplitude_mm, self.max_mm_s)
        fut = self.ctl.run_steps(f"{self.name}.shake", steps, timeout_s=total + 5.0)
        return self._job("shake", fut)

    def speed(self) -> float:
        """Commanded speed (mm/s), as last asked for."""
        return self._commanded

    def position(self) -> int:
        """Latest count (distance events, and a TP read at most every 0.1 s)."""
        self.ctl.refresh_position(self.axis)
        pos = self.ctl.position(self.axis)
        return 0 if pos is None else pos

    def _card_fault(self) -> CardFault:
        return CardFault(f"{self.name}: Galil card fault, belts stopped: "
                             f"{self.ctl.card_fault}; an operator's reset restarts the "
                             f"card's programs")

    def fault(self) -> HalError | None:
        """What stops the belt while we want it to run: a card fault (a program thread
        that cannot be restarted, a stuck input monitor: reported whatever the belt does,
        until an operator's reset), the motor off (off-on-error, the e-stop, an operator),
        a limit switch, the card's watchdog, or a stall — jogging, yet the encoder moved
        less than ``galil.stall_mm`` (a servo dithers a few counts either way) in
        ``STALL_S``. Cleared by the next command."""
        if self.ctl.card_fault is not None:
            return self._card_fault()
        if self._mode == "idle":
            self._stall_ref = None
            return None
        if not self.ctl.connected:          # nothing is known of the belt: not a stall
            self._stall_ref = None
            return CommsLost(f"{self.name}: the Galil link is down; the driver reconnects")
        st = self.ctl.status(self.axis)
        if st is not None and st.t >= self._commanded_at:
            if st.motor_off:
                return ConveyorFault(f"{self.name}: motor off on Galil axis {self.axis} "
                                     f"({stop_text(st.stop_code)}); an operator's reset "
                                     f"turns it on")
        events = {kind for kind, _, t in list(self.ctl.card_events) if t >= self._commanded_at}
        if "LIMSWI" in events:
            # the card's #LIMSWI said so; _LF/_LR are only reported (their polarity is a
            # wiring matter: docs/real-cell.md)
            return ConveyorFault(f"{self.name}: a limit switch tripped on the Galil "
                                 f"(#LIMSWI); axis {self.axis} stopped")
        if "WATCHDOG" in events:
            return watchdog_stopped(self.name, self.ctl.spec.watchdog_s)
        if self._mode != "jog" or abs(self._commanded) < 1.0:
            self._stall_ref = None
            return None
        now, pos = self.clock.now(), self.position()
        age = self.ctl.position_age(self.axis)
        if age is None or age > FRESH_S:
            # no fresh count: a link that answers garbage, or silent and not yet timed out,
            # says nothing of the belt. Judged on a stale count, a belt the card's watchdog
            # stopped meanwhile would be called a jam and shaken.
            self._stall_ref = None
            return None
        ref = self._stall_ref
        if ref is None or abs(diff(pos, ref[1], COUNTER_BITS)) > self._stall_counts:
            self._stall_ref = (now, pos)
            return None
        if now - ref[0] < STALL_S:
            return None
        return ConveyorFault(f"{self.name} conveyor stalled: the encoder moved less than "
                             f"{self._stall_counts} counts in {now - ref[0]:.1f} s at "
                             f"{self._commanded:g} mm/s")

    def position_age(self) -> float | None:
        """Clock seconds since ``position()``'s count was read (None: never). An encoder
        sync must anchor only on a fresh count."""
        return self.ctl.position_age(self.axis)

    def position_rtt(self) -> float:
        """Seconds the read behind ``position()`` took to come back (its timing's doubt)."""
        return self.ctl.position_rtt(self.axis)

    def read_position(self) -> Job:
        """A fresh ``TP`` read now; the job's result is the count (for anchoring a sync)."""
        return self._job("read_position", self.ctl.submit(self.ctl.read_position, self.axis))

    def travelled(self, distance_mm: float) -> Job:
        """Ends when the count has moved ``distance_mm`` on from the latest count now."""
        return _TravelJob(self, distance_mm)

    # ---------------------------------------------------------------- latch, servo
    def arm_latch(self) -> Job:
        """``AL``: arm the position latch (the camera trigger is wired to its input)."""
        return self._job("arm_latch", self.ctl.command(f"AL{self.axis}"))

    def read_latch(self, timeout_s: float = 1.0) -> Job:
        """Result: the count latched at the trigger. Polls ``_ALx`` (1 while armed) until
        it reads 0, then ``_RLx``; fails after ``timeout_s`` if the latch never trips."""
        axis = self.axis

        def tripped():
            return RETRY if parse_int(self.ctl.ask(f"MG _AL{axis}")) else None

        def latched():
            return parse_int(self.ctl.ask(f"MG _RL{axis}"))

        fut = self.ctl.run_steps(
            f"{self.name}.read_latch", [tripped, latched], timeout_s=timeout_s,
            on_timeout=lambda: HalError(f"{self.name}: latch on Galil axis {axis} not tripped "
                                        f"within {timeout_s:g} s (no camera trigger seen on "
                                        f"the latch input?)"))
        return self._job("read_latch", fut)

    def abort(self) -> Job:
        """``AB 1``: stop every axis at once, leaving the card's programs running."""
        self._commanded = 0.0
        self._mode = "idle"
        return self._job("abort", self.ctl.command("AB 1"))

    def servo(self, on: bool) -> Job:
        """``SH`` (servo here: motor on) or ``MO`` (motor off). ``SH`` is a person's: the
        operator's Start or Reset, or commissioning's question; nothing else turns a motor
        on. It also clears a card fault (``GalilController.reset_card``) first."""
        if not on:
            return self._job("servo", self.ctl.command(f"MO{self.axis}"))

        def reset_and_servo() -> str:
            self.ctl.reset_card()
            if self.ctl.card_fault is not None:
                raise self._card_fault()
            return self.ctl.ask(f"SH{self.axis}")
        return self._job("servo", self.ctl.submit(reset_and_servo))


class _TravelJob(Job):
    """Belt-distance notification: succeeds once the count is ``distance`` on from the start.

    No thread per job: ``poll()`` compares the controller's latest count (kept fresh by the
    notifier's ``D`` messages and rate-limited ``TP`` reads) with the target.
    """

    def __init__(self, conveyor: GalilConveyor, distance_mm: float) -> None:
        super().__init__(f"{conveyor.name}.travelled({distance_mm:g})")
        self.conveyor = conveyor
        self.target = conveyor._counts(distance_mm)
        conveyor.ctl.refresh_position(conveyor.axis)
        self.base = conveyor.ctl.position(conveyor.axis)     # None until first known

    def poll(self) -> JobState:
        if self.state is JobState.RUNNING:
            self.conveyor.ctl.refresh_position(self.conveyor.axis)
            now = self.conveyor.ctl.position(self.conveyor.axis)
            if now is None:
                return self.state
            if self.base is None:
                self.base = now
            moved = diff(now, self.base, COUNTER_BITS)
            if (moved >= self.target if self.target >= 0 else moved <= self.target):
                self.succeed(self.conveyor.clock.now())
        return self.state


def active_low(sig: IoSignal) -> bool:
    """The input reads 0 while the signal is active: ``active: low`` (or the older
    ``active_low: true``). An e-stop or a limit wired normally closed is one (a broken
    wire then reads as pressed); its polarity is a cell setting, checked at commissioning."""
    return bool(getattr(sig, "active_low", False)) or getattr(sig, "active", "high") == "low"


class GalilIO:
    """The digital I/O of a Galil controller under the cell's signal names.

    Outputs are set with ``SB``/``CB``; inputs come from the input monitor's ``I`` messages
    (and the read at connect), so ``get`` never waits on the link.
    """

    def __init__(self, controller: GalilController, signals: dict[str, IoSignal],
                 clock: Clock | None = None) -> None:
        self.ctl = controller
        self.clock = clock or controller.clock
        self.inputs = {n: s.bit for n, s in signals.items()
                       if s.controller == "galil" and s.dir == "in"}
        self.active_low = {n for n, s in signals.items()
                           if s.controller == "galil" and s.dir == "in" and active_low(s)}
        self.outputs = {n: s.bit for n, s in signals.items()
                        if s.controller == "galil" and s.dir != "in"}
        self._lock = threading.Lock()
        self._changes: list[IoChange] = []
        self._last: int | None = controller.inputs_mask
        self._out: dict[str, bool] = {}
        controller.subscribe(self._on_event)
        # the inputs read at every connect are a sample too: a change between the connect
        # and the input monitor's first message, or during an outage, is not lost
        controller.on_connect(lambda: self._observe(self.ctl.inputs_mask, self.clock.now()))

    def _on_event(self, ev: Event, t: float) -> None:
        if isinstance(ev, InputsEvent):
            self._observe(ev.mask, t)

    def _observe(self, mask: int | None, t: float) -> None:
        """A sample of the inputs: each named input whose level changed since the last
        sample is a change (``changes``)."""
        if mask is None:
            return
        with self._lock:
            last, self._last = self._last, mask
            if last is None:
                return
            for name, bit in self.inputs.items():
                was, now = bool(last >> (bit - 1) & 1), bool(mask >> (bit - 1) & 1)
                if was != now:
                    self._changes.append(IoChange(name, now != (name in self.active_low), t))

    def get(self, signal: str | int) -> bool:
        """A signal by the cell's name, or an input by its Galil bit number (cached)."""
        if isinstance(signal, int):
            mask = self.ctl.inputs_mask
            return bool(signal >= 1 and mask is not None and mask >> (signal - 1) & 1)
        if signal in self.inputs:
            mask = self.ctl.inputs_mask
            if mask is None:
                return False
            return bool(mask >> (self.inputs[signal] - 1) & 1) != (signal in self.active_low)
        if signal in self.outputs:
            with self._lock:
                if signal in self._out:
                    return self._out[signal]
            mask = self.ctl.outputs_mask
            return bool(mask is not None and mask >> (self.outputs[signal] - 1) & 1)
        return False

    def set(self, signal: str | int, value: bool) -> Job:
        """An output by the cell's name or by its Galil bit number: ``SB n``/``CB n``."""
        if isinstance(signal, int) and 1 <= signal <= 16:
            bit = signal
            signal = next((n for n, b in self.outputs.items() if b == bit), f"galil.out{bit}")
        elif signal in self.outputs:
            bit = self.outputs[signal]
        else:
            return DoneJob(f"io.set({signal})",
                           error=HalError(f"{signal!r} is not a Galil output"))
        fut = self.ctl.command(f"{'SB' if value else 'CB'} {bit}")

        def done(f) -> None:
            if not f.cancelled() and f.exception() is None:
                with self._lock:
                    self._out[signal] = bool(value)
        fut.add_done_callback(done)
        return FutureJob(f"io.set({signal})", fut, self.clock)

    def changes(self) -> list[IoChange]:
        with self._lock:
            out, self._changes = self._changes, []
        return out


__all__ = ["GalilConveyor", "GalilIO", "DistanceEvent"]
