"""The Galil emulator's simulated axes: the state of each axis (``_Axis``), the motion
and latch commands (``AC`` ``DC`` ``SP`` ``PR`` ``JG`` ``BG`` ``AB`` ``SH`` ``OE`` ``ER``
``TL`` ``TK`` ``CN`` ``MO`` ``ST`` ``TP`` ``TV`` ``AL`` ``RL``), their argument forms, the
amplifier chain, the position error and the axis faults tests trip. A mixin of
``GalilEmulator`` (``emulators.galil``), which holds the state named below.

The card as the Galil command reference describes it (docs/real-cell.md has the sources):
``TE`` is the commanded minus the measured position; past ``ER`` (default 16384 counts)
with ``OE 1`` the motor goes off (stop code 8) and ``#POSERR`` runs; ``SH`` takes the
present position as the command, clearing the error. An axis whose encoder is wired
reversed (``reversed_encoders``, a fault a test sets) measures the opposite of the motion
the motor makes, so its error grows at twice the speed from its first motion after ``SH``
until ``ER`` trips it. ``CN n0`` says at which level a limit switch is active; a switch is
wired so that pressing it pulls its input low (``limit_wiring``), and an axis refuses
``BG`` towards an active limit (code 22)."""

from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass

from feeder_bt.emulators.galil.dmc import AXES, DmcError, DmcInterpreter
from feeder_bt.sim.realtime import Plant


@dataclass
class _Axis:
    letter: str
    ac: float = 256000.0
    dc: float = 256000.0
    sp: float = 25000.0
    jg: float = 0.0
    pr: float = 0.0
    pending: str = "move"          # what the next BG starts: "jog" after JG, "move" after PR
    jogging: bool = False
    servo: bool = False
    latch_armed: bool = False
    latched: int = 0
    oe: int = 0                    # off-on-error
    er: float = 16384.0            # error limit (counts)
    sc: int = 1                    # stop code (see _SC)
    te: float = 0.0                # position error (counts)
    lf: int = 1                    # forward limit switch pressed: 0 (1: released)
    lr: int = 1
    tl: float = 9.9982             # continuous torque limit, volts (the card's default)
    tk: float = 0.0                # peak torque limit (0: off)
    base: float = 0.0              # plant count at SH (the error is measured from there)
    tripped: bool = False          # the error is over ER: #POSERR already ran



class AxisCommands:
    """Axis state and motion commands of the emulator; mixed into ``GalilEmulator``."""

    plant: Plant
    lock: threading.RLock
    axes: dict[str, _Axis]
    interp: DmcInterpreter
    latch_input: int
    _latch_lock: threading.Lock
    _estop_signal: str | None
    estops: int
    _stop: threading.Event
    reversed_encoders: set[str]    # axes whose encoder counts against the motor (a fault)
    limit_wiring: str              # "low": a pressed limit switch pulls its input low
    cn: list[float]                # CN n0..n4 (limit, home, latch, selective abort, abort)


    # ================================================================ amplifiers
    def _amplifier_loop(self) -> None:
        """The e-stop chain: while the e-stop input is active every amplifier is off."""
        was = False
        while not self._stop.wait(0.01):
            if self._estop_signal is None:
                continue
            now = self.plant.signal(self._estop_signal)
            if now and not was:
                self.estops += 1
            if now:
                self._motors_off(None, stop_code=6)
            was = now
            self._position_errors()

    def _position_errors(self) -> None:
        """``TE`` of each servoed axis; past ``ER`` the card's off-on-error and #POSERR."""
        trips = []
        with self.lock:
            for st in self.axes.values():
                if not st.servo or self.plant.axis(st.letter) is None:
                    continue
                moved = self.plant.position_counts(st.letter) - st.base
                st.te = 2.0 * moved if st.letter in self.reversed_encoders else 0.0
                if st.er >= 0 and abs(st.te) > st.er and not st.tripped:
                    st.tripped = True
                    trips.append((st.letter, st.oe))
        for letter, oe in trips:
            if oe in (1, 3):
                self._motors_off(letter, stop_code=8)
            self.interp.interrupt("#POSERR", 0)

    def _motors_off(self, letters: str | None, stop_code: int) -> None:
        with self.lock:
            for st in self.axes.values():
                if letters is not None and st.letter not in letters:
                    continue
                if st.servo:
                    st.sc = stop_code
                st.servo, st.jogging = False, False
                if self.plant.axis(st.letter) is not None and self._moving(st.letter):
                    self.plant.jog(st.letter, 0.0, max(st.dc, 1e6))


    # ================================================================ test hooks
    def trip_position_error(self, axis: str, error_counts: float = 1e5) -> None:
        """The position error of ``axis`` exceeds ``ER`` (a jam): with ``OE`` set the motor
        goes off; ``#POSERR`` runs if the program has it."""
        with self.lock:
            st = self._axis(axis.upper())
            st.te = error_counts
            oe = st.oe
        if oe:
            self._motors_off(axis.upper(), stop_code=8)
        self.interp.interrupt("#POSERR", 0)

    def trip_limit(self, axis: str, forward: bool = True) -> None:
        """A limit switch of ``axis`` is pressed. Active at the level ``CN`` names, moving
        towards it: the axis stops and ``#LIMSWI`` runs (Galil command reference,
        #LIMSWI); at the wrong polarity the card sees nothing."""
        with self.lock:
            st = self._axis(axis.upper())
            if forward:
                st.lf = 0
            else:
                st.lr = 0
            active = self._limit_active(st, forward)
            if active:
                st.jogging = False
                st.sc = 2 if forward else 3
                if self.plant.axis(st.letter) is not None and self._moving(st.letter):
                    self.plant.jog(st.letter, 0.0, st.dc)
        if active:
            self.interp.interrupt("#LIMSWI", 0)

    def _limit_active(self, st: _Axis, forward: bool) -> bool:
        """A limit input at the level ``CN n0`` calls active (-1: low, 1: high)."""
        pressed = (st.lf if forward else st.lr) == 0
        level = (0 if self.limit_wiring == "low" else 1) if pressed else \
            (1 if self.limit_wiring == "low" else 0)
        return level == (0 if self.cn[0] < 0 else 1)

    def trip_amplifier(self, axis: str) -> None:
        """The amplifier of ``axis`` reports a fault: it turns the motor off; ``#AMPERR``
        runs if the program has it."""
        self._motors_off(axis.upper(), stop_code=6)
        self.interp.interrupt("#AMPERR", 0)

    def clear_limits(self) -> None:
        with self.lock:
            for st in self.axes.values():
                st.lf = st.lr = 1


    # ---------------------------------------------------------------- argument forms
    def _axes_arg(self, rest: str) -> list[_Axis]:
        """``BGB``/``ST AB``/``ST`` (all axes) -> axis states."""
        letters = rest.replace(" ", "").upper()
        if not letters:
            return list(self.axes.values())
        if not all(c in AXES for c in letters):
            raise DmcError(4, rest)
        return [self._axis(c) for c in letters]

    def _axis(self, letter: str) -> _Axis:
        st = self.axes.get(letter)
        if st is None:
            st = self.axes[letter] = _Axis(letter)
        return st

    def _values_arg(self, rest: str) -> tuple[dict[str, float], bool]:
        """``,500`` / ``B=500`` / ``?`` / ``B=?`` -> ({axis: value}, is_query)."""
        m = re.match(r"^([A-H]+)\s*=\s*(.*)$", rest)
        if m:
            if m.group(2).strip() == "?":
                return {c: math.nan for c in m.group(1)}, True
            value = self.interp.evaluate(m.group(2))
            return {c: value for c in m.group(1)}, False
        if rest.strip() == "?":
            return {a: math.nan for a in self.axes}, True
        if not rest.strip():
            raise DmcError(50, "no value")
        out: dict[str, float] = {}
        fields = rest.split(",")
        if len(fields) > len(AXES):
            raise DmcError(50, rest)
        query = False
        for i, f in enumerate(fields):
            f = f.strip()
            if not f:
                continue
            if f == "?":
                out[AXES[i]] = math.nan
                query = True
            else:
                out[AXES[i]] = self.interp.evaluate(f)
        return out, query

    def _set_or_query(self, attr: str, rest: str, check=None) -> str:
        values, query = self._values_arg(rest)
        with self.lock:
            if query:
                return ",".join(_num(getattr(self._axis(a), attr)) for a in values)
            for a, v in values.items():
                if check is not None:
                    check(a, v)
                setattr(self._axis(a), attr, v)
        return ""

    # ---------------------------------------------------------------- motion
    def _cmd_AC(self, rest: str) -> str:
        return self._set_or_query("ac", rest, _positive)

    def _cmd_DC(self, rest: str) -> str:
        return self._set_or_query("dc", rest, _positive)

    def _cmd_SP(self, rest: str) -> str:
        return self._set_or_query("sp", rest, _speed)

    def _cmd_PR(self, rest: str) -> str:
        out = self._set_or_query("pr", rest, _range)
        if not out:
            values, _ = self._values_arg(rest)
            with self.lock:
                for a in values:
                    self._axis(a).pending = "move"
        return out

    def _cmd_JG(self, rest: str) -> str:
        values, query = self._values_arg(rest)
        if query:
            return self._set_or_query("jg", rest)
        with self.lock:
            for a, v in values.items():
                _speed(a, abs(v))
                st = self._axis(a)
                if self._moving(a) and not st.jogging:
                    raise DmcError(13, f"JG on axis {a} during a position move")
            for a, v in values.items():
                st = self._axis(a)
                st.jg, st.pending = v, "jog"
                if st.jogging and self.plant.axis(a) is not None:
                    self.plant.jog(a, v, st.ac if abs(v) >= abs(self._velocity(a)) else st.dc)
        return ""

    def _cmd_BG(self, rest: str) -> str:
        with self.lock:
            axes = self._axes_arg(rest)
            for st in axes:
                if not st.servo:
                    raise DmcError(20, f"axis {st.letter}")
                if self._moving(st.letter):
                    raise DmcError(21, f"axis {st.letter}")
                ahead = (st.jg if st.pending == "jog" else st.pr) >= 0
                if self._limit_active(st, forward=ahead):
                    raise DmcError(22, f"axis {st.letter}")
            for st in axes:
                if self.plant.axis(st.letter) is None:
                    continue
                if st.pending == "jog":
                    st.jogging = True
                    self.plant.jog(st.letter, st.jg, st.ac)
                else:
                    st.jogging = False
                    self.plant.move(st.letter, st.pr, st.sp, st.ac)
        return ""

    def _cmd_AB(self, rest: str) -> str:
        """``AB``: abort motion and programs; ``AB 1``: motion only."""
        if rest.strip() not in ("", "0", "1"):
            raise DmcError(4, rest)
        if rest.strip() != "1":
            self.interp.halt()
        with self.lock:
            for st in self.axes.values():
                st.jogging = False
                axis = self.plant.axis(st.letter)
                if axis is not None and self._moving(st.letter):
                    self.plant.jog(st.letter, 0.0, 1e9)
        return ""

    def _cmd_SH(self, rest: str) -> str:
        if self._estop_signal is not None and self.plant.signal(self._estop_signal):
            raise DmcError(20, "amplifier enable chain open (e-stop)")
        with self.lock:
            for st in self._axes_arg(rest):
                st.servo = True
                st.te, st.tripped = 0.0, False
                if self.plant.axis(st.letter) is not None:
                    st.base = float(self.plant.position_counts(st.letter))
        return ""

    def _cmd_OE(self, rest: str) -> str:
        return self._set_or_query("oe", rest)

    def _cmd_ER(self, rest: str) -> str:
        return self._set_or_query("er", rest, _error_limit)

    def _cmd_TL(self, rest: str) -> str:
        return self._set_or_query("tl", rest, _volts)

    def _cmd_TK(self, rest: str) -> str:
        return self._set_or_query("tk", rest, _volts)

    def _cmd_CN(self, rest: str) -> str:
        """``CN n0,n1,n2,n3,n4``: limit, home and latch polarity (-1 or 1), selective abort
        inputs (0 or 1), abort input ends programs (0) or not (1)."""
        fields = [f.strip() for f in rest.split(",")]
        if not rest.strip() or len(fields) > 5:
            raise DmcError(50 if not rest.strip() else 4, rest)
        allowed = ((-1, 1), (-1, 1), (-1, 1), (0, 1), (0, 1))
        with self.lock:
            new = list(self.cn)
            for i, f in enumerate(fields):
                if not f:
                    continue
                v = self.interp.evaluate(f)
                if v not in allowed[i]:
                    raise DmcError(6, f"CN field {i}: {f}")
                new[i] = v
            self.cn = new
        return ""

    def _cmd_MO(self, rest: str) -> str:
        with self.lock:
            for st in self._axes_arg(rest):
                if self._moving(st.letter):
                    raise DmcError(7, f"MO while axis {st.letter} moves")
                st.servo = False
        return ""

    def _cmd_ST(self, rest: str) -> str:
        with self.lock:
            for st in self._axes_arg(rest):
                st.jogging = False
                st.sc = 4
                if self.plant.axis(st.letter) is not None and self._moving(st.letter):
                    self.plant.jog(st.letter, 0.0, st.dc)
        return ""

    def _cmd_TP(self, rest: str) -> str:
        return ",".join(_num(self._measured(st.letter)) for st in self._axes_arg(rest))

    def _measured(self, letter: str, t: float | None = None) -> float:
        """What the axis's encoder counts: the plant's count, or, wired reversed, the
        count at ``SH`` minus the motion since."""
        count = self.plant.position_counts(letter, t)
        if letter not in self.reversed_encoders:
            return count
        base = self._axis(letter).base
        return base - (count - base)

    def _cmd_TV(self, rest: str) -> str:
        return ",".join(_num(round(self.plant.velocity_counts(st.letter)))
                         for st in self._axes_arg(rest))

    # ---------------------------------------------------------------- latch
    def _cmd_AL(self, rest: str) -> str:
        with self.lock:
            axes = self._axes_arg(rest)
        with self._latch_lock:
            for st in axes:
                st.latch_armed = True
        return ""

    def _cmd_RL(self, rest: str) -> str:
        with self.lock:
            axes = self._axes_arg(rest)
        with self._latch_lock:
            return ",".join(_num(st.latched) for st in axes)

    def _on_trigger(self, t: float) -> None:
        """Camera trigger -> ``latch_input``: an input latches only its own axis (input 1
        axis A, ... input 8 axis H), so a miswired cell latches nothing on the latch axis."""
        if not 1 <= self.latch_input <= len(AXES):
            return
        letter = AXES[self.latch_input - 1]
        st = self.axes.get(letter)
        if st is None or not st.latch_armed:
            return
        count = self._measured(letter, t)
        with self._latch_lock:
            if st.latch_armed:
                st.latched, st.latch_armed = count, False

    # ================================================================ helpers
    def _moving(self, letter: str) -> bool:
        st = self.axes.get(letter)
        if st is not None and st.jogging:
            return True
        return self.plant.in_motion(letter)

    def _velocity(self, letter: str) -> float:
        return self.plant.velocity_counts(letter)


def _num(value: float) -> str:
    """Integers as TP/TV print them: a sign column and digits."""
    v = int(round(value))
    return f"-{-v}" if v < 0 else f" {v}"


def _positive(axis: str, value: float) -> None:
    if not 0 < value <= 1.07e9:
        raise DmcError(6, f"axis {axis}: {value}")


def _error_limit(axis: str, value: float) -> None:
    if not -1 <= value <= 2147483647:
        raise DmcError(6, f"axis {axis}: {value}")


def _volts(axis: str, value: float) -> None:
    if not 0 <= value <= 9.9982:
        raise DmcError(6, f"axis {axis}: {value}")


def _speed(axis: str, value: float) -> None:
    if not 0 <= abs(value) <= 12e6:
        raise DmcError(6, f"axis {axis}: {value}")


def _range(axis: str, value: float) -> None:
    if not -(2**31) <= value < 2**31:
        raise DmcError(6, f"axis {axis}: {value}")

