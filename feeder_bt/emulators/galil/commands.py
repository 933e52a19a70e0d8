"""The Galil emulator's command line: ``execute`` (one command, from a link or a running
program), digital I/O (``SB`` ``CB`` ``OB`` ``TI``), status and settings (``TC`` ``CW``
``EO``), ``MG``, the program commands (``XQ`` ``HX`` ``DL``) and the callbacks the DMC
interpreter makes on its host (operands, functions, commands, output, errors). A mixin of
``GalilEmulator`` (``emulators.galil``), which holds the state named below."""

from __future__ import annotations

import re
import threading

from feeder_bt.emulators.galil.axes import _num
from feeder_bt.emulators.galil.dmc import (
    AXES,
    DmcError,
    DmcInterpreter,
    format_number,
    is_axis_command,
)
from feeder_bt.emulators.galil.link import Link as _Link
from feeder_bt.emulators.galil.link import PtyLink as _PtyLink
from feeder_bt.hal.galil.conveyor import active_low
from feeder_bt.hal.galil.protocol import ERROR_TEXT, MODEL
from feeder_bt.sim.realtime import Plant

COPYRIGHT = f"Galil Motion Control {MODEL} emulator (feeder_bt), firmware EMU1.0"
OUTPUT_BITS = 16
INPUT_BITS = 16


class ControllerCommands:
    """The command dispatcher, I/O, status, programs and the DmcHost callbacks; mixed into
    ``GalilEmulator``."""

    plant: Plant
    lock: threading.RLock
    interp: DmcInterpreter
    outputs: int
    tc: int
    cw_msb: bool
    echo: bool
    cf: str | None
    input_count: int
    _links: list[_Link]
    _links_lock: threading.Lock


    # ================================================================ commands
    def execute(self, cmd: str, from_program: bool = False) -> str:
        """Carry out one command; return its reply data ('' for none). Raises DmcError."""
        s = cmd.strip()
        if not s or s.startswith("'"):
            return ""
        if s == "\x12\x16":                   # ^R^V: revision information
            return f"{MODEL} Rev EMU1.0"
        if s[:2] == "IH":
            if from_program:
                raise DmcError(6, "IH from a program is not emulated")
            return self._cmd_IH(s[2:].strip())
        m = re.match(r"^([A-Za-z][A-Za-z0-9]*)\s*=\s*(.*)$", s)
        if m and not is_axis_command(m.group(1)):
            name, rhs = m.group(1), m.group(2).strip()
            if rhs == "?":
                return format_number(self.interp._env.variable(name))
            self.interp.assign(name, rhs)
            return ""
        name, rest = s[:2], s[2:]
        if not re.match(r"^[A-Z]{2}$", name):
            raise DmcError(1, s)
        handler = getattr(self, f"_cmd_{name}", None)
        if handler is None:
            raise DmcError(1, s)
        if from_program and name in ("DL", "ED", "EO", "CW"):
            raise DmcError(3, s)
        out = handler(rest.strip()) or ""
        if name == "ST" and not rest.strip() and not from_program:
            self.interp.halt()          # a bare ST from the host ends every program too
        return out

    # ---------------------------------------------------------------- I/O
    def _signal(self, bit: int, direction: str) -> str | None:
        for name, sig in self.plant.cell.io.items():
            if sig.controller == "galil" and sig.bit == bit and sig.dir == direction:
                return name
        if direction == "out":
            return self.plant.signal_at("galil", bit)
        return None

    def _read_outputs(self) -> int:
        mask = 0
        for bit in range(1, OUTPUT_BITS + 1):
            name = self._signal(bit, "out")
            if name is not None and self.plant.signal(name):
                mask |= 1 << (bit - 1)
        return mask

    def _inputs(self) -> int:
        """Input levels: an active-low signal reads 0 while active."""
        mask = 0
        for bit in range(1, INPUT_BITS + 1):
            name = self._signal(bit, "in")
            if name is None:
                continue
            low = active_low(self.plant.cell.io[name])
            if self.plant.signal(name) != low:
                mask |= 1 << (bit - 1)
        return mask

    def _set_output(self, bit: int, value: bool) -> None:
        if not 1 <= bit <= OUTPUT_BITS:
            raise DmcError(6, f"output {bit}")
        with self.lock:
            if value:
                self.outputs |= 1 << (bit - 1)
            else:
                self.outputs &= ~(1 << (bit - 1))
        name = self._signal(bit, "out")
        if name is not None:
            self.plant.set_signal(name, value)

    def _bit_arg(self, rest: str) -> int:
        value = self.interp.evaluate(rest)
        if value != int(value):
            raise DmcError(6, rest)
        return int(value)

    def _cmd_SB(self, rest: str) -> str:
        self._set_output(self._bit_arg(rest), True)
        return ""

    def _cmd_CB(self, rest: str) -> str:
        self._set_output(self._bit_arg(rest), False)
        return ""

    def _cmd_OB(self, rest: str) -> str:
        parts = rest.split(",")
        if len(parts) != 2:
            raise DmcError(50, rest)
        self._set_output(self._bit_arg(parts[0]), bool(self.interp.evaluate(parts[1])))
        return ""

    def _cmd_TI(self, rest: str) -> str:
        bank = int(self.interp.evaluate(rest)) if rest.strip() else 0
        self._check_bank(bank, DmcError(6, f"TI {rest}"))
        return _num((self._inputs() >> (8 * bank)) & 0xFF)

    def _check_bank(self, bank: int, error: DmcError) -> None:
        """TI 1 (inputs 9-16) exists on a 5-8 axis card only (Galil command reference)."""
        if not 0 <= bank < self.input_count // 8:
            raise error

    # ---------------------------------------------------------------- status, settings
    def _cmd_TC(self, rest: str) -> str:
        with self.lock:
            code = self.tc
        if rest.strip() == "1":
            return f"{code} {ERROR_TEXT.get(code, 'Unrecognized command')}" if code else "0"
        if rest.strip() not in ("", "0"):
            raise DmcError(4, rest)
        return str(code)

    def _cmd_CW(self, rest: str) -> str:
        arg = rest.split(",")[0].strip()
        if arg in ("", "0", "?"):
            return COPYRIGHT
        if arg == "1":
            self.cw_msb = True
        elif arg == "2":
            self.cw_msb = False
        else:
            raise DmcError(6, rest)
        return ""

    def _cmd_EO(self, rest: str) -> str:
        if rest.strip() not in ("0", "1"):
            raise DmcError(6, rest)
        self.echo = rest.strip() == "1"
        return ""

    def _cmd_NO(self, rest: str) -> str:
        return ""

    def _cmd_MG(self, rest: str) -> str:
        return self.interp.message(rest).rstrip("\r\n")

    # ---------------------------------------------------------------- programs
    def _cmd_XQ(self, rest: str) -> str:
        m = re.match(r"^(#[A-Za-z0-9]+)\s*(?:,\s*(.+))?$", rest.strip())
        if not m:
            raise DmcError(11, rest)
        thread = int(self.interp.evaluate(m.group(2))) if m.group(2) else 0
        self.interp.execute(m.group(1), thread)
        return ""

    def _cmd_HX(self, rest: str) -> str:
        if rest.strip():
            self.interp.halt(int(self.interp.evaluate(rest)))
        else:
            self.interp.halt()
        return ""

    def _cmd_DL(self, rest: str) -> str:
        raise DmcError(3 if rest.strip() else 2, "DL")      # only as a whole command line

    # ================================================================ DmcHost
    def operand(self, name: str, suffix: str) -> float:
        """Operands for expressions: ``_TPB``, ``_BGB``, ``_TI0``, ``_ALB``, ``_RLB`` ..."""
        if name in ("TP", "TV", "BG", "AL", "RL", "SP", "AC", "DC", "JG", "PR"):
            if len(suffix) != 1 or suffix not in AXES:
                raise DmcError(4, f"_{name}{suffix}")
            if name == "TP":
                return float(self._measured(suffix))
            if name == "TV":
                return float(round(self.plant.velocity_counts(suffix)))
            if name == "BG":
                return 1.0 if self._moving(suffix) else 0.0
            with self.lock:
                st = self._axis(suffix)
            if name == "AL":
                with self._latch_lock:
                    return 1.0 if st.latch_armed else 0.0
            if name == "RL":
                with self._latch_lock:
                    return float(st.latched)
            return float(getattr(st, name.lower()))
        if name == "TI":
            bank = int(suffix or "0")
            self._check_bank(bank, DmcError(4, f"_TI{suffix}"))
            return float((self._inputs() >> (8 * bank)) & 0xFF)
        if name == "OP":
            bank = int(suffix or "0")
            with self.lock:
                return float((self.outputs >> (8 * bank)) & 0xFF)
        if name == "TC" and not suffix:
            with self.lock:
                return float(self.tc)
        if name == "CW" and not suffix:
            return 1.0 if self.cw_msb else 2.0
        if name == "XQ":
            return float(self.interp.thread_line(int(suffix or "0")))
        if name == "ED":
            with self.interp.lock:
                return float(self.interp.error_thread if suffix == "1"
                             else self.interp.error_line)
        if name in ("MO", "SC", "TE", "LF", "LR", "OE", "ER", "TL", "TK"):
            if len(suffix) != 1 or suffix not in AXES:
                raise DmcError(4, f"_{name}{suffix}")
            with self.lock:
                st = self._axis(suffix)
                if name == "MO":
                    return 0.0 if st.servo else 1.0
                if name == "SC":
                    return float(0 if self._moving(suffix) else st.sc)
                if name in ("LF", "LR"):        # 0: the switch forbids that direction
                    return 0.0 if self._limit_active(st, name == "LF") else 1.0
                return float(getattr(st, name.lower()))
        if name == "CN" and suffix in ("0", "1", "2", "3", "4"):
            with self.lock:
                return float(self.cn[int(suffix)])
        raise DmcError(1, f"_{name}{suffix}")

    def function(self, name: str, arg: float) -> float:
        n = int(arg)
        if name == "IN":
            if not 1 <= n <= INPUT_BITS:
                raise DmcError(56, f"@IN[{n}]")
            return float((self._inputs() >> (n - 1)) & 1)
        if name == "OUT":
            if not 1 <= n <= OUTPUT_BITS:
                raise DmcError(56, f"@OUT[{n}]")
            with self.lock:
                return float((self.outputs >> (n - 1)) & 1)
        raise DmcError(57, f"@{name}")

    def command(self, text: str, thread: int) -> None:
        data = self.execute(text, from_program=True)
        if data:
            self.output(data + "\r\n")

    def output(self, text: str) -> None:
        """Program output: only to the handle ``CF`` names (before any ``CF``: the serial
        port). Nobody there: the message is lost, as on the card."""
        data = self._unsolicited_bytes(text)
        cf = self.cf
        with self._links_lock:
            links = [x for x in self._links if not x.closed.is_set()
                     and (x.handle == cf if cf is not None else isinstance(x, _PtyLink))]
        for link in links:
            link.write(data)

    def thread_error(self, thread: int, error: DmcError, line: int, text: str,
                     trapped: bool = False) -> None:
        """A program line failed: the card echoes it, numbered, with a ``?`` after it (unless
        the program's ``#CMDERR`` took over)."""
        with self.lock:
            self.tc = error.code
        if not trapped:
            self.output(f"{line:03d} {text.strip()}?\r\n")

    def _unsolicited_bytes(self, text: str) -> bytes:
        raw = text.encode("ascii", errors="replace")
        return bytes(b | 0x80 for b in raw) if self.cw_msb else raw

