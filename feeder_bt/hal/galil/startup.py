"""The start-up sequence and the health poll of the Galil driver, kept
apart from the link handling of ``driver``: which handle we are, ``CF``, ``IH`` clean-up,
halting only our threads, the safety settings (``ER`` ``TL`` ``TK`` ``OE`` ``CN``), ``SH``
only as the cell description allows, and the periodic poll that pets the card's watchdog,
re-asserts ``CF``, restarts a dead program thread, watches the input monitor's heartbeat
and reads each axis's status. A thread that cannot be restarted, or a heartbeat that
stopped, is a card fault: our belts are stopped at once (``ST`` with our axes named).

Command facts: Galil's DMC command reference (galil.com; the entries for CF, CN, ER, OE,
SH, ST, TI, TK, TL, #POSERR, #LIMSWI, read in a public copy; docs/real-cell.md)."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from feeder_bt.hal.galil.link import Connection, retrieve
from feeder_bt.hal.galil.protocol import AXES, THREADS, GalilError, parse_int, positional

if TYPE_CHECKING:
    from feeder_bt.core.model import GalilSpec

log = logging.getLogger("feeder_bt.hal.galil.driver")

INPUT_MONITOR = "#INMON"        # galil_programs/monitor.dmc, thread 0
DIST_NOTIFIER = "#DIST"         # galil_programs/monitor.dmc, thread 1
WATCHDOG = "#WDOG"              # galil_programs/monitor.dmc, thread 2
OUR_THREADS = {0: INPUT_MONITOR, 1: DIST_NOTIFIER, 2: WATCHDOG}
HEALTH_S = 0.2                  # health poll period (watchdog pets, threads, heartbeat)
STATUS_EVERY = 3                # axis status every 3rd poll (0.6 s)
CF_EVERY = 5                    # CF re-asserted every 5th poll (1 s)
MAX_RESTARTS = 3                # a thread dead more often than this within RESTART_WINDOW_S
RESTART_WINDOW_S = 60.0         # ... cannot be restarted: a card fault


@dataclass(frozen=True)
class AxisStatus:
    """One axis as the health poll last read it (``MG _MOx`` ...)."""

    motor_off: bool          # _MO: the amplifier is off
    stop_code: int           # _SC
    position_error: float    # _TE, counts
    forward_limit: bool      # _LF reads 0: the forward limit switch is active
    reverse_limit: bool      # _LR reads 0
    t: float                 # clock time of the read


class CardSetup:
    """Mixed into ``GalilController``: what it tells and asks the card besides commands."""

    spec: GalilSpec
    servo_axes: str
    handle: str | None
    cpm: float
    card_fault: str | None
    program_errors: list[str]
    restarts: dict[int, int]
    thread_lines: dict[int, int]
    _held_handles: set[str]
    _deaths: dict[int, list[float]]
    _beat: tuple[int, float] | None
    _has_monitor: bool
    _has_notifier: bool
    _has_watchdog: bool

    def _ask_on(self, conn: Connection, text: str, payload: bytes | None = None) -> str:
        raise NotImplementedError

    def ask(self, text: str) -> str:
        raise NotImplementedError

    def submit(self, fn: Any, *args: Any) -> Any:
        raise NotImplementedError

    def _claim_handle(self, conn: Connection) -> None:
        """``WH``, then ``CF`` our handle (program messages to us) and ``IH`` the stale
        handles of our earlier connections (or every other one, ``free_handles: others``)."""
        try:
            which = self._ask_on(conn, "WH").strip().upper()
        except GalilError:
            which = ""
        if not (len(which) == 3 and which.startswith("IH") and which[2] in AXES):
            self.handle = None                 # serial: messages come to the serial port
            return
        self.handle = which[2]
        self._ask_on(conn, f"CF {self.handle}")
        mode = self.spec.free_handles
        if mode == "others":
            self._ask_on(conn, "IHN=>-2")
        elif mode == "ours":
            for h in sorted(self._held_handles - {self.handle}):
                try:
                    self._ask_on(conn, f"IH{h}=>-2")
                except GalilError:             # already free: nothing to do
                    pass
        self._held_handles = {self.handle}

    def _halt_our_threads(self, conn: Connection) -> None:
        """``HXn`` of our threads; a program on any other thread is not ours to kill."""
        foreign = []
        for n in range(THREADS):
            line = parse_int(self._ask_on(conn, f"MG _XQ{n}"))
            if line < 0:
                continue
            if n in OUR_THREADS:
                self._ask_on(conn, f"HX{n}")
            else:
                foreign.append(f"thread {n} (line {line})")
        if foreign:
            raise GalilError(17, f"a program not ours runs on {', '.join(foreign)}: the "
                                 f"driver will not halt it (HX) and DL is refused while it "
                                 f"runs; stop it at the controller (docs/real-cell.md)")

    def _servo_at_connect(self, conn: Connection, first: bool) -> None:
        """``SH`` as ``spec.servo_on`` allows; never an error (the axis reports motor off)."""
        rule = self.spec.servo_on
        if not self.servo_axes:
            return
        if not first:
            off = [a for a in self.servo_axes if parse_int(self._ask_on(conn, f"MG _MO{a}"))]
            self.servo_refused = (f"motor {', '.join(off)} off after the reconnect: left off "
                                  f"until an operator's reset") if off else None
            if rule != "reconnect":
                return
        elif rule == "never":
            self.servo_refused = ("galil.servo_on is never: the motors go on when a person "
                                  "asks (the operator's Start or Reset, commissioning)")
            return
        try:
            self._ask_on(conn, f"SH{self.servo_axes}")
            self.servo_refused = None
        except GalilError as e:                # e.g. the e-stop holds the amplifiers off
            self.servo_refused = f"SH{self.servo_axes} refused: {e.text}"
            log.warning("Galil: %s", self.servo_refused)

    def _send_safety(self, conn: Connection) -> None:
        """The cell file's safety settings on our axes, at every connect (a card reset or
        another host may have changed them): ``ER`` the error limit in counts (a reversed
        encoder trips it within a few mm, not at the default 16384 counts), ``TL`` the
        continuous torque limit with ``TK 0`` (no peak above it), ``OE`` and ``CN`` (limit
        switch and latch polarity; inputs 5-8 stay general inputs, not selective aborts;
        the abort input stops motion but not our programs)."""
        axes = self.servo_axes
        if not axes:
            return
        er = max(1, round(self.spec.error_limit_mm * self.cpm))
        self._ask_on(conn, positional("ER", {a: er for a in axes}))
        self._ask_on(conn, positional("TL", {a: self.spec.torque_limit_v for a in axes}))
        self._ask_on(conn, positional("TK", {a: 0 for a in axes}))
        oe = 1 if self.spec.off_on_error else 0
        self._ask_on(conn, positional("OE", {a: oe for a in axes}))
        limit = 1 if self.spec.limit_switches == "high" else -1
        latch = 1 if self.spec.latch_edge == "rising" else -1
        self._ask_on(conn, f"CN {limit},-1,{latch},0,1")

    def _set_program_variables(self, conn: Connection) -> None:
        """What monitor.dmc reads from the host before its threads start."""
        if self._has_notifier:
            step = max(1, round(self.spec.notify_mm * self.cpm))
            self._ask_on(conn, f"DSTEP={step}")
            self._ask_on(conn, f"DAXIS={AXES.index(self.spec.latch_axis.upper())}")
        if self._has_watchdog:
            self._ask_on(conn, f"WDMS={round(self.spec.watchdog_s * 1000)}")
            self._ask_on(conn, f"WDAXES={sum(1 << AXES.index(a) for a in self.servo_axes)}")
        if self._has_monitor:
            self._ask_on(conn, f"INBANKS={2 if self.spec.inputs > 8 else 1}")
        self._ask_on(conn, "ERSEEN=0")

    def _read_inputs(self, conn: Connection) -> int:
        """Inputs 1-8, and 9-16 on a card that has them; a card refusing ``_TI1`` while the
        cell says 16 is a wrong ``galil.inputs``, said so."""
        mask = parse_int(self._ask_on(conn, "MG _TI0"))
        if self.spec.inputs > 8:
            try:
                mask |= parse_int(self._ask_on(conn, "MG _TI1")) << 8
            except GalilError as e:
                raise GalilError(e.code, f"galil.inputs is 16 but the card refuses _TI1 "
                                         f"({e.text}): a 1-4 axis card has inputs 1-8 only; "
                                         f"set galil.inputs: 8", command="MG _TI1") from None
        return mask

    # ================================================================ card faults
    def _card_failed(self, why: str) -> None:
        """Latch a card fault and stop our belts now (device worker only)."""
        if self.card_fault is not None:
            return
        self.card_fault = why
        self.program_errors.append(why)
        log.error("Galil card fault: %s; stopping axes %s", why, self.servo_axes)
        if self.servo_axes:
            try:
                self.ask(f"ST{self.servo_axes}")      # never a bare ST: other programs' axes
            except GalilError as e:
                log.error("Galil: ST%s refused: %s", self.servo_axes, e)

    def reset_card(self) -> None:
        """The operator's reset (device worker): forget the card fault and the deaths
        counted so far, re-arm the automatic subroutines' reports and start any of our
        threads that is not running; a thread that will not start is a card fault again."""
        self.card_fault = None
        self._deaths.clear()
        self._beat = None
        self.ask("ERSEEN=0")
        for n, label in self._threads_wanted().items():
            if parse_int(self.ask(f"MG _XQ{n}")) < 0:
                try:
                    self.ask(f"XQ {label},{n}")
                except GalilError as e:
                    self._card_failed(f"program thread {n} ({label}) will not start: "
                                      f"XQ refused ({e.text})")

    def _threads_wanted(self) -> dict[int, str]:
        wanted = {0: self._has_monitor, 1: self._has_notifier, 2: self._has_watchdog}
        return {n: label for n, label in OUR_THREADS.items() if wanted[n]}

    def _check_threads(self) -> None:
        """Each of our threads runs; a dead one is started again unless it has died more
        than ``MAX_RESTARTS`` times in ``RESTART_WINDOW_S`` (or ``XQ`` is refused): then it
        cannot be restarted, a card fault. The input monitor's ``INBEAT`` must move."""
        now = self.clock.now()
        for n, label in self._threads_wanted().items():
            line = parse_int(self.ask(f"MG _XQ{n}"))
            self.thread_lines[n] = line
            if line >= 0 or self.card_fault is not None:
                continue
            why = f"program thread {n} ({label}) is not running"
            self.program_errors.append(why)
            log.warning("Galil: %s", why)
            deaths = [t for t in self._deaths.get(n, []) if now - t < RESTART_WINDOW_S]
            deaths.append(now)
            self._deaths[n] = deaths
            if len(deaths) > MAX_RESTARTS:
                self._card_failed(f"program thread {n} ({label}) died {len(deaths)} times in "
                                  f"{RESTART_WINDOW_S:g} s: it cannot be restarted")
                continue
            try:
                self.ask(f"XQ {label},{n}")
                self.restarts[n] = self.restarts.get(n, 0) + 1
            except GalilError as e:
                self._card_failed(f"program thread {n} ({label}) cannot be restarted: "
                                  f"XQ refused ({e.text})")
        if self._has_monitor and self.spec.heartbeat_s > 0 and self.card_fault is None \
                and self.thread_lines.get(0, -1) >= 0:
            self._check_heartbeat(now)

    def _check_heartbeat(self, now: float) -> None:
        try:
            beat = parse_int(self.ask("MG INBEAT"))
        except GalilError:                  # not defined yet: the thread has just started
            return
        if self._beat is None or beat != self._beat[0]:
            self._beat = (beat, now)
        elif now - self._beat[1] > self.spec.heartbeat_s:
            self._card_failed(f"the input monitor (#INMON, thread 0) has not counted its "
                              f"heartbeat for {now - self._beat[1]:.1f} s: it is stuck, and "
                              f"inputs (a jam, the e-stop) go unseen")

    # ================================================================ health poll
    def _health_tick(self) -> None:
        """Every ``HEALTH_S``: one health poll (it also reconnects a dropped link at once,
        so that the card's watchdog is petted again as soon as the link is back)."""
        if self._closed:
            return
        if not self._health_busy:
            self._health_busy = True
            fut = self.submit(self._health)
            fut.add_done_callback(retrieve)
            fut.add_done_callback(lambda f: setattr(self, "_health_busy", False))
        self._sched.call_later(HEALTH_S, self._health_tick)

    def _health(self) -> None:
        """Pet the watchdog, re-assert ``CF`` (a card reset forgets it), check our threads
        and the heartbeat (every poll); read each axis's status (every ``STATUS_EVERY``
        polls, so that a serial link is not kept busy)."""
        if self._has_watchdog:
            self.ask("WDCNT=0")
        self._health_n = getattr(self, "_health_n", -1) + 1
        if self.handle is not None and self._health_n % CF_EVERY == 0:
            self.ask(f"CF {self.handle}")
        self._check_threads()
        if self._health_n % STATUS_EVERY:
            return
        now = self.clock.now()
        for a in self.servo_axes:
            st = AxisStatus(
                motor_off=bool(parse_int(self.ask(f"MG _MO{a}"))),
                stop_code=parse_int(self.ask(f"MG _SC{a}")),
                position_error=float(parse_int(self.ask(f"MG _TE{a}"))),
                forward_limit=parse_int(self.ask(f"MG _LF{a}")) == 0,
                reverse_limit=parse_int(self.ask(f"MG _LR{a}")) == 0, t=now)
            with self._lock:
                self._status[a] = st
