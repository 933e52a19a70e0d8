"""The start-up sequence and the health poll of the Galil driver (issue 15), kept apart
from the link handling of ``driver``: which handle we are, ``CF``, ``IH`` clean-up, halting
only our threads, ``SH`` as the cell description allows, and the periodic poll that pets
the card's watchdog, restarts a dead program thread and reads each axis's status."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from .link import Connection, retrieve
from .protocol import AXES, THREADS, GalilError, parse_int

if TYPE_CHECKING:
    from ...scenario.model import GalilSpec

log = logging.getLogger("feeder_bt.hal.galil.driver")

INPUT_MONITOR = "#INMON"        # galil_programs/monitor.dmc, thread 0
DIST_NOTIFIER = "#DIST"         # galil_programs/monitor.dmc, thread 1
WATCHDOG = "#WDOG"              # galil_programs/monitor.dmc, thread 2
OUR_THREADS = {0: INPUT_MONITOR, 1: DIST_NOTIFIER, 2: WATCHDOG}
HEALTH_S = 0.2                  # health poll period (watchdog pets, thread and axis status)
STATUS_EVERY = 3                # thread and axis status every 3rd poll (0.6 s)
MAX_RESTARTS = 5                # a program thread restarted more often: left stopped


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
    _held_handles: set[str]

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
        if not self.servo_axes or rule == "never":
            self.servo_refused = "galil.servo_on is never: an operator turns the motors on"
            return
        if rule == "start" and not first:
            off = [a for a in self.servo_axes if parse_int(self._ask_on(conn, f"MG _MO{a}"))]
            self.servo_refused = (f"motor {', '.join(off)} off after the reconnect: left off "
                                  f"until an operator's reset") if off else None
            return
        try:
            self._ask_on(conn, f"SH{self.servo_axes}")
            self.servo_refused = None
        except GalilError as e:                # e.g. the e-stop holds the amplifiers off
            self.servo_refused = f"SH{self.servo_axes} refused: {e.text}"
            log.warning("Galil: %s", self.servo_refused)

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
        """Pet the watchdog (every poll); check our threads run and read each axis's status
        (every ``STATUS_EVERY`` polls, so that a serial link is not kept busy)."""
        if self._has_watchdog:
            self.ask("WDCNT=0")
        self._health_n = getattr(self, "_health_n", -1) + 1
        if self._health_n % STATUS_EVERY:
            return
        wanted = {0: self._has_monitor, 1: self._has_notifier, 2: self._has_watchdog}
        for n, label in OUR_THREADS.items():
            if not wanted[n]:
                continue
            line = parse_int(self.ask(f"MG _XQ{n}"))
            self.thread_lines[n] = line
            if line >= 0:
                continue
            why = f"program thread {n} ({label}) is not running"
            self.program_errors.append(why)
            log.warning("Galil: %s", why)
            if self.restarts.get(n, 0) < MAX_RESTARTS:
                self.restarts[n] = self.restarts.get(n, 0) + 1
                self.ask(f"XQ {label},{n}")
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

