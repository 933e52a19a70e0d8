"""The Galil emulator's simulated axes: the state of each axis (``_Axis``), the motion
and latch commands (``AC`` ``DC`` ``SP`` ``PR`` ``JG`` ``BG`` ``AB`` ``SH`` ``OE`` ``ER``
``MO`` ``ST`` ``TP`` ``TV`` ``AL`` ``RL``), their argument forms, the amplifier chain and
the axis faults tests trip. A mixin of ``GalilEmulator`` (``emulators.galil``), which
holds the state named below."""

from __future__ import annotations

import math
import re
import threading
from dataclasses import dataclass

from .dmc import AXES, DmcError, DmcInterpreter
from .plant import Plant


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
    lf: int = 1                    # forward limit switch: 1 inactive, 0 tripped
    lr: int = 1



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
        """A limit switch of ``axis`` trips: the axis stops; ``#LIMSWI`` runs."""
        with self.lock:
            st = self._axis(axis.upper())
            if forward:
                st.lf = 0
            else:
                st.lr = 0
            st.jogging = False
            st.sc = 2 if forward else 3
            if self.plant.axis(st.letter) is not None and self._moving(st.letter):
                self.plant.jog(st.letter, 0.0, st.dc)
        self.interp.interrupt("#LIMSWI", 0)

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
                st.te = 0.0
        return ""

    def _cmd_OE(self, rest: str) -> str:
        return self._set_or_query("oe", rest)

    def _cmd_ER(self, rest: str) -> str:
        return self._set_or_query("er", rest, _positive)

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
        return ",".join(_num(self.plant.position_counts(st.letter))
                         for st in self._axes_arg(rest))

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
        count = self.plant.position_counts(letter, t)
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


def _speed(axis: str, value: float) -> None:
    if not 0 <= abs(value) <= 12e6:
        raise DmcError(6, f"axis {axis}: {value}")


def _range(axis: str, value: float) -> None:
    if not -(2**31) <= value < 2**31:
        raise DmcError(6, f"axis {axis}: {value}")

