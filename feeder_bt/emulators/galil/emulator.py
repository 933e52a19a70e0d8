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
- The position error (``TE``) against ``ER``, ``OE``, ``TL``/``TK`` and ``CN`` as in
  ``galil_axes``; an encoder wired reversed (``reversed_encoders``) trips ``ER``.
- ``_TI1``/``TI 1`` exist only on a card with 16 inputs (``inputs``; a 5-8 axis card).
- A bare ``ST`` from the host ends every program as well as the motion.
- The serial port echoes every character until ``EO 0``.
- The latch of an axis is its fixed latch input (input 1 for A ... 8 for H); the camera
  trigger is wired to ``galil.latch_input``.
"""

from __future__ import annotations

import argparse
import re
import socket
import sys
import threading
import time

from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.emulators.galil.axes import AxisCommands, _Axis
from feeder_bt.emulators.galil.commands import (
    COPYRIGHT,
    INPUT_BITS,
    OUTPUT_BITS,
    ControllerCommands,
)
from feeder_bt.emulators.galil.dmc import AXES, DmcError, DmcInterpreter, Program
from feeder_bt.emulators.galil.link import POLL_S
from feeder_bt.emulators.galil.link import Link as _Link
from feeder_bt.emulators.galil.link import PtyLink as _PtyLink
from feeder_bt.emulators.galil.link import Session as _Session
from feeder_bt.emulators.galil.link import TcpLink as _TcpLink
from feeder_bt.hal.galil.protocol import HANDLES, MODEL
from feeder_bt.sim.realtime import Plant

__all__ = ["COPYRIGHT", "INPUT_BITS", "OUTPUT_BITS", "REJECT_CODES", "GalilEmulator", "main",
           "run_forever", "serve"]

# Codes a ``reject`` fault answers with: what a real card would plausibly say to that command.
REJECT_CODES = {"BG": 22, "JG": 6, "SP": 6, "PR": 6, "AC": 6, "DC": 6, "XQ": 19, "DL": 17,
                "SH": 20, "AL": 7, "RL": 7, "TP": 7, "MG": 1, "SB": 6, "CB": 6}


class GalilEmulator(AxisCommands, ControllerCommands):
    """A Galil controller on ``host:port`` (and optionally a pty) acting on ``plant``: the
    server, its handles and command lines here; the axes in ``galil_axes``, the other
    commands and the interpreter's host callbacks in ``galil_commands``."""

    def __init__(self, plant: Plant, host: str = "127.0.0.1", port: int = 0,
                 faults: FaultPlan | None = None, pty: bool = False,
                 handles: int = HANDLES, inputs: int | None = None) -> None:
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
        # the card's digital inputs: 8 on a 1-4 axis card, 16 on a 5-8 axis card (TI 1);
        # by default the card the cell describes, so a test can give it the other
        self.input_count = inputs or spec.inputs
        self.reversed_encoders: set[str] = set()   # a wiring fault a test sets
        self.limit_wiring = "low"              # a pressed limit switch pulls its input low
        self.cn: list[float] = [-1, -1, -1, 0, 0]  # CN's power-on defaults
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



# ==================================================================== entry points


def serve(plant: Plant, host: str = "127.0.0.1", port: int = 0,
          faults: FaultPlan | None = None) -> GalilEmulator:
    """Start a Galil emulator on ``host:port`` acting on a started ``plant``."""
    return GalilEmulator(plant, host, port, faults).start()


def run_forever(host: str, port: int, scenario: str, cell: str | None = None,
                seed: int = 1, reversed_encoders: str = "") -> None:
    """``feeder emulate galil``: a plant and an emulator until Ctrl-C. ``reversed_encoders``
    (axis letters) wires those encoders reversed, to rehearse the error-limit trip."""
    from feeder_bt.config.loader import load_scenario

    sc, cell_spec = load_scenario(scenario, cell)
    plant = Plant(sc, cell_spec, seed=seed).start()
    emu = serve(plant, host, port)
    emu.reversed_encoders.update(c for c in reversed_encoders.upper() if c in AXES)
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
    ap.add_argument("--reversed-encoder", default="", metavar="AXES",
                    help="axes whose encoder is wired reversed (e.g. B): the first motion "
                         "after SH trips the error limit")
    args = ap.parse_args(argv)
    run_forever(args.host, args.port, args.scenario, args.cell, args.seed,
                args.reversed_encoder)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
