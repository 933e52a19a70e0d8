"""A Galil DMC-21x3 emulator: a real TCP server (or a pty) speaking the DMC ASCII protocol,
backed by the simulated cell (``Plant``).

What a driver sees is what a real controller does: commands end with CR or ``;`` (several
per line); each answers ``data\\r\\n:`` or ``:``, or a lone ``?`` when rejected, after which
``TC1`` tells the code and text. ``CW 1`` sets the top bit of every unsolicited byte (the
``MG`` output of running programs). ``DL`` ... ``\\`` downloads a program, which runs under
``XQ`` on the DMC interpreter of ``emulators.dmc``, so the programs of ``galil_programs/``
are exercised for real. Axes map to the plant's conveyors (``cell.galil.axes``); digital
I/O bits map to the cell's named signals (``cell.io`` with ``controller: galil``); the
latch of ``cell.galil.latch_axis`` is captured at the plant's camera trigger (the trigger
is wired to the latch input, thesis 2.3.2).

A fault plan (controller ``galil``) can reject a command (``?`` with a plausible code),
drop the connection, or stall a reply.

As strict as the controller (docs/real-cell.md has the sources):

- Ethernet *handles*: at most ``handles`` TCP clients (8 on a DMC, ``HANDLES``); another
  connection is reset. A handle is freed when its client closes the connection; a link
  dropped from this side (a pulled cable, ``drop_clients``) leaves its handle *stale*
  until ``IH h=>-2`` frees it, as the card never saw the cable go.
- Program output (``MG`` of a running thread, error echoes) goes only to the handle that
  ``CF`` names; before any ``CF`` only to the serial port (pty): a TCP host that never sends
  ``CF`` gets no messages.
- Amplifiers are off (``_MO`` 1) until ``SH``; the e-stop input (the cell's ``estop``
  signal, wired into the amplifier enable chain) and an off-on-error trip (``OE``) turn
  them off again, and only a new ``SH`` turns them on.
- The serial port echoes every character until ``EO 0``.
- The latch of an axis is its fixed latch input (input 1 for A ... 8 for H); the camera
  trigger is wired to ``galil.latch_input``.
"""

from __future__ import annotations

import argparse
import math
import re
import socket
import sys
import threading
import time
from dataclasses import dataclass

from ..hal.galil.protocol import ERROR_TEXT, HANDLES, MODEL
from .dmc import AXES, DmcError, DmcInterpreter, Program, format_number, is_axis_command
from .faults import FaultPlan
from .galil_link import POLL_S
from .galil_link import Link as _Link
from .galil_link import PtyLink as _PtyLink
from .galil_link import Session as _Session
from .galil_link import TcpLink as _TcpLink
from .plant import Plant

COPYRIGHT = f"Galil Motion Control {MODEL} emulator (feeder_bt), firmware EMU1.0"

# Codes a ``reject`` fault answers with: what a real card would plausibly say to that command.
REJECT_CODES = {"BG": 22, "JG": 6, "SP": 6, "PR": 6, "AC": 6, "DC": 6, "XQ": 19, "DL": 17,
                "SH": 20, "AL": 7, "RL": 7, "TP": 7, "MG": 1, "SB": 6, "CB": 6}
OUTPUT_BITS = 16
INPUT_BITS = 16


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


class GalilEmulator:
    """A Galil controller on ``host:port`` (and optionally a pty) acting on ``plant``."""

    def __init__(self, plant: Plant, host: str = "127.0.0.1", port: int = 0,
                 faults: FaultPlan | None = None, pty: bool = False,
                 handles: int = HANDLES) -> None:
        self.plant = plant
        self.host = host
        self.port = port
        self.faults = faults
        self.want_pty = pty
        self.pty_path: str | None = None
        spec = plant.cell.galil
        self.latch_axis = spec.latch_axis.upper()
        letters = sorted(set("AB") | {a.upper() for a in spec.axes.values()})
        self.axes = {a: _Axis(a) for a in letters}
        for a, st in self.axes.items():
            axis = plant.axis(a)
            if axis is not None:
                st.ac = st.dc = axis.accel * plant.cpm
        self.cw_msb = False
        self.echo = True                       # serial port only; EO 0 turns it off
        self.max_handles = handles
        self.cf: str | None = None             # handle letter for program output; None: serial
        self._local = threading.local()        # the link whose command is being run
        self.latch_input = spec.latch_input or AXES.index(self.latch_axis) + 1
        sig = plant.cell.io.get("estop")
        self._estop_signal = "estop" if sig is not None else None
        self.estops = 0
        self.tc = 0
        self.lock = threading.RLock()          # emulator state; never taken under plant.lock
        self._latch_lock = threading.Lock()    # latch fields only (taken in the trigger)
        self.interp = DmcInterpreter(self)
        self.outputs = 0
        self.commands: list[str] = []          # every command received, for tests
        self._links: list[_Link] = []
        self._links_lock = threading.Lock()
        self._inject: bytes | None = None
        self._server: socket.socket | None = None
        self._threads: list[threading.Thread] = []
        self._stop = threading.Event()
        self._started = False

    # ================================================================ life
    def start(self) -> GalilEmulator:
        """Bind, listen and serve in background threads; ``port`` holds the bound port."""
        if self._started:
            return self
        self._started = True
        with self.lock:
            self.outputs = self._read_outputs()
        self.plant.on_trigger(self._on_trigger)
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind((self.host, self.port))
        srv.listen(2)
        srv.settimeout(POLL_S)
        self._server = srv
        self.port = srv.getsockname()[1]
        self._spawn(self._accept_loop, "galil-emu-accept")
        self._spawn(self._amplifier_loop, "galil-emu-amps")
        if self.want_pty:
            self.serve_pty()
        return self

    def serve_pty(self) -> str:
        """Also serve on a pseudo-terminal; returns the slave's path for ``serial_for_url``."""
        if self.pty_path is None:
            link = _PtyLink()
            self.pty_path = link.path
            self._add_link(link)
            self._spawn(lambda: self._serve_link(link), "galil-emu-pty")
        return self.pty_path

    def stop(self) -> None:
        """Stop serving: close every link, halt the programs, join the threads."""
        self._stop.set()
        self.interp.halt()
        if self._server is not None:
            try:
                self._server.close()
            except OSError:
                pass
        with self._links_lock:
            links, self._links = self._links, []
        for link in links:
            link.close()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(2.0)
        self._threads = []

    def __enter__(self) -> GalilEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def _spawn(self, fn, name: str) -> None:
        t = threading.Thread(target=fn, name=name, daemon=True)
        self._threads = [x for x in self._threads if x.is_alive()]
        self._threads.append(t)
        t.start()

    def _accept_loop(self) -> None:
        assert self._server is not None
        n = 0
        while not self._stop.is_set():
            try:
                sock, _ = self._server.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            n += 1
            link = _TcpLink(sock, f"tcp{n}")
            letter = self._free_handle()
            if letter is None:                 # every handle taken: the card resets it
                link.close()
                continue
            link.handle = letter
            self._add_link(link)
            self._spawn(lambda link=link: self._serve_link(link), f"galil-emu-{link.name}")

    def _add_link(self, link: _Link) -> None:
        with self._links_lock:
            self._links = [x for x in self._links if not self._released(x)]
            self._links.append(link)

    @staticmethod
    def _released(link: _Link) -> bool:
        """A link that holds no handle any more: closed by its client, or freed by IH."""
        return link.closed.is_set() and (link.handle is None or link.client_closed)

    def _free_handle(self) -> str | None:
        with self._links_lock:
            used = {x.handle for x in self._links if x.handle and not self._released(x)}
        return next((h for h in AXES[:self.max_handles] if h not in used), None)

    def handles(self) -> dict[str, str]:
        """Handle letter -> 'open' or 'stale' (for tests and ``TH``)."""
        with self._links_lock:
            return {x.handle: ("stale" if x.closed.is_set() else "open")
                    for x in self._links if x.handle and not self._released(x)}

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

    def _serve_link(self, link: _Link) -> None:
        session = _Session(self, link)
        while not self._stop.is_set() and not link.closed.is_set():
            try:
                data = link.read()
            except OSError:
                break
            if data:
                session.feed(data)
        link.close()

    # ================================================================ test hooks
    def drop_clients(self) -> None:
        """Close every TCP client socket from the server side (as a cable pull would). The
        card never sees the cable go: each handle stays taken (stale) until ``IH``."""
        with self._links_lock:
            tcp = [x for x in self._links if isinstance(x, _TcpLink)]
        for link in tcp:
            link.close()

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

    def inject_into_next_reply(self, text: str) -> None:
        """Write ``text`` as unsolicited output in the middle of the next reply."""
        self._inject = self._unsolicited_bytes(text)

    def inject_unsolicited(self, text: str) -> None:
        """Send ``text`` as unsolicited output now (as an ``MG`` from a program would)."""
        self.output(text)

    # ================================================================ command line
    def _handle(self, link: _Link, cmd: str) -> bool:
        """Run one command from a link and reply; True when it starts a download."""
        cmd = cmd.strip()
        self._local.link = link
        self.commands.append(cmd)
        rule = self.faults.check("galil", cmd) if self.faults is not None and cmd else None
        if rule is not None and rule.kind == "drop":
            if isinstance(link, _PtyLink):
                return False                   # a serial line cannot be dropped: no reply
            link.close()
            return False
        if rule is not None and rule.kind == "reject":
            with self.lock:
                self.tc = REJECT_CODES.get(cmd[:2].upper(), 1)
            self._reply(link, b"?")
            return False
        if cmd[:2] == "DL" and cmd[2:].strip() == "":
            if self.interp.running():
                with self.lock:
                    self.tc = 17
                self._reply(link, b"?")
                return False
            return True
        try:
            data = self.execute(cmd)
            out = (data + "\r\n:" if data else ":").encode("ascii", errors="replace")
        except DmcError as e:
            with self.lock:
                self.tc = e.code
            out = b"?"
        if rule is not None and rule.kind == "stall":
            if link.closed.wait(rule.stall_s) or self._stop.is_set():
                return False
        self._reply(link, out)
        return False

    def _finish_download(self, link: _Link, text: str) -> None:
        lines = [ln for ln in re.split(r"\r\n|\r|\n", text) if ln.strip()]
        try:
            prog = Program.parse(lines)
            self.interp.load(prog)
            out = b":"
        except DmcError as e:
            with self.lock:
                self.tc = e.code
            out = b"?"
        self._reply(link, out)

    def _reply(self, link: _Link, data: bytes) -> None:
        inject, self._inject = self._inject, None
        if inject:
            k = max(1, len(data) // 2)
            link.write(data[:k] + inject + data[k:])
        else:
            link.write(data)

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
        m = re.match(r"^~([a-h])\s*=\s*(.*)$", s)
        if m:
            if m.group(2).strip() == "?":
                with self.interp.lock:
                    return f" {self.interp.axis_vars.get(m.group(1), 0)}"
            self.interp.set_axis_var(m.group(1), m.group(2))
            return ""
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
        return handler(rest.strip()) or ""

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
            low = getattr(self.plant.cell.io[name], "active_low", False)
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
        return _num((self._inputs() >> (8 * bank)) & 0xFF)

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

    # ---------------------------------------------------------------- handles
    def _cmd_WH(self, rest: str) -> str:
        """Which handle: ``IHA`` ... for a TCP client, ``RS232`` on the serial port."""
        link = getattr(self._local, "link", None)
        if link is None or link.handle is None:
            return "RS232"
        return f"IH{link.handle}"

    def _cmd_CF(self, rest: str) -> str:
        """Send program output to handle ``h`` (``CF h``), or ``S`` the serial port."""
        arg = rest.strip().upper()
        if arg == "S":
            self.cf = None
        elif len(arg) == 1 and arg in AXES[:self.max_handles]:
            self.cf = arg
        else:
            raise DmcError(4, rest)
        return ""

    def _cmd_TH(self, rest: str) -> str:
        return "\r\n".join(f"IH{h} TCP {state.upper()}"
                            for h, state in sorted(self.handles().items())) or "NO HANDLES"

    def _cmd_IH(self, rest: str) -> str:
        """``IHh=>-2`` (or ``>-1``, ``>-3``) frees handle h; ``S`` the sender's, ``N`` all but
        the sender's. Opening client handles is not emulated."""
        m = re.match(r"^([A-HSN])\s*=\s*>\s*(-[123])$", rest.upper())
        if not m:
            raise DmcError(6, f"IH{rest}")
        me = getattr(self._local, "link", None)
        which = m.group(1)
        with self._links_lock:
            links = [x for x in self._links if x.handle and not self._released(x)]
        for link in links:
            if (which == "S" and link is me) or (which == "N" and link is not me) \
                    or link.handle == which:
                link.client_closed = True
                link.close()
                if self.cf == link.handle:
                    self.cf = None
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
                return float(self.plant.position_counts(suffix))
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
        if name in ("MO", "SC", "TE", "LF", "LR", "OE", "ER"):
            if len(suffix) != 1 or suffix not in AXES:
                raise DmcError(4, f"_{name}{suffix}")
            with self.lock:
                st = self._axis(suffix)
                if name == "MO":
                    return 0.0 if st.servo else 1.0
                if name == "SC":
                    return float(0 if self._moving(suffix) else st.sc)
                return float(getattr(st, name.lower()))
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


# ==================================================================== entry points


def serve(plant: Plant, host: str = "127.0.0.1", port: int = 0,
          faults: FaultPlan | None = None) -> GalilEmulator:
    """Start a Galil emulator on ``host:port`` acting on a started ``plant``."""
    return GalilEmulator(plant, host, port, faults).start()


def run_forever(host: str, port: int, scenario: str, cell: str | None = None,
                seed: int = 1) -> None:
    """``feeder emulate galil``: a plant and an emulator until Ctrl-C."""
    from ..scenario.loader import load_scenario

    sc, cell_spec = load_scenario(scenario, cell)
    plant = Plant(sc, cell_spec, seed=seed).start()
    emu = serve(plant, host, port)
    print(f"Galil {MODEL} emulator on {host}:{emu.port} (scenario {scenario}); Ctrl-C stops",
          flush=True)
    try:
        while plant.error is None:
            time.sleep(0.5)
        print(f"plant stopped: {plant.error}", file=sys.stderr)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
        plant.stop()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="feeder emulate galil",
                                 description="Galil DMC emulator backed by the simulated cell")
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=0, help="TCP port (0: any free port)")
    ap.add_argument("--scenario", default="scenarios/lenses.yaml")
    ap.add_argument("--cell", default=None, help="cell description overriding the scenario's")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    run_forever(args.host, args.port, args.scenario, args.cell, args.seed)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
