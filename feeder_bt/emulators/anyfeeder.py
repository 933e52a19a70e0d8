"""An AnyFeeder emulator over the simulated plate: ``feeder emulate plate``.

It listens on 127.0.0.1 and passes the feeder's bytes raw, as a serial-to-Ethernet bridge
in a plant would, so the driver reaches it with ``socket://127.0.0.1:PORT``. As strict as
the Adept AnyFeeder User's Guide (Rev. B, 3.6) allows us to be: a line that is not the
syntax, an unknown command or a value out of range gets ``m12``/``m22`` ("Invalid
command"); any command before the init gets ``m16``/``m26`` ("not initialized"); after a
servo error (``m13``) every command but the reset gets ``m17``/``m27`` ("Error must be
reset before operation can continue"). A command while an action runs is refused with
``m12``/``m22`` — the Guide does not say what the feeder answers then (docs/plate-
feeders.md: check at commissioning). An action answers ``m11``, ``m21`` at once and
``m20``, ``m10`` when the simulated plate is at rest (Table 3-6).

Faults for tests and rehearsals: ``servo_error_at`` (the Nth action ends ``m13``) and
``no_sync_at`` (the Nth action ends ``m28``); in a whole emulated run, a fault plan's
``servo_timeout`` rule for controller ``plate`` (``emulators.faults``; its ``command``
matched against the action's line, e.g. ``x=1``) ends the matching action ``m13``.
"""

from __future__ import annotations

import socket
import threading

from feeder_bt.core.plate_model import PlateCommands
from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.emulators.line_server import LineServer
from feeder_bt.hal.anyfeeder.protocol import (
    BACKLIGHT_OFF,
    BACKLIGHT_ON,
    CR,
    OUTPUT_PARAM,
    PURGE_TURNS,
    SPEED,
    SPEED_PARAMS,
    TURNS,
    ProtocolError,
    parse_command,
)
from feeder_bt.sim.realtime import Plant

PLATE_FAULTS = ("servo_timeout",)    # the fault plan's kinds this emulator acts on


class AnyFeederEmulator(LineServer):
    """One client at a time on ``port`` (0: any free port, see ``.port``)."""

    terminator = CR
    thread_name = "anyfeeder-emulator"

    def __init__(self, plant: Plant, host: str = "127.0.0.1", port: int = 0,
                 servo_error_at: int | None = None, no_sync_at: int | None = None,
                 faults: FaultPlan | None = None) -> None:
        self.plant = plant
        self.plate = plant.hal.plate
        self.cmds: PlateCommands = plant.cell.plate.commands
        self.params: dict[int, int] = {1: 3, 2: 3}      # Table 3-7 defaults
        self.initialised = False
        self.error_state = False
        self.busy = False
        self.actions = 0
        self.servo_error_at, self.no_sync_at = servo_error_at, no_sync_at
        self.faults = faults            # controller "plate": servo_timeout ends it m13
        for rule in faults.rules if faults is not None else ():
            if rule.controller == "plate" and rule.kind not in PLATE_FAULTS:
                raise ValueError(f"the AnyFeeder emulator cannot inject {rule.kind!r}; "
                                 f"plate faults: {', '.join(PLATE_FAULTS)}")
        self.lines: list[str] = []                      # what it received, for tests
        self._send_lock = threading.Lock()
        super().__init__(host, port)

    def on_line(self, conn: socket.socket, line: bytes) -> None:
        self._line(conn, line.decode("ascii", "replace"))

    def _send(self, conn: socket.socket, *codes: str) -> None:
        with self._send_lock:
            try:
                conn.sendall(b"".join(c.encode("ascii") + CR for c in codes))
            except OSError:
                pass

    # ------------------------------------------------------------------ the feeder
    def _line(self, conn: socket.socket, text: str) -> None:
        self.lines.append(text)
        try:
            cmd = parse_command(text)
        except ProtocolError:
            return self._send(conn, "m12", "m22")
        if self.busy:
            return self._send(conn, "m12", "m22")
        if cmd.param is not None and not self._value_ok(cmd.param, cmd.value):
            return self._send(conn, "m12", "m22")
        if cmd.execute is None:                      # a parameter set: no response
            self.params[cmd.param] = cmd.value
            return None
        number = cmd.execute
        if cmd.param is not None:
            self.params[cmd.param] = cmd.value
        if number == self.cmds.reset:
            self.error_state = False
            self.initialised = False                 # homed again after a reset
            return self._send(conn, "m11", "m21", "m20", "m10")
        if self.error_state:
            return self._send(conn, "m17", "m27")
        if number == self.cmds.init:
            return self._start(conn, number, lambda: self.plate.init(), init=True)
        if not self.initialised:
            return self._send(conn, "m16", "m26")
        if number in SPEED_PARAMS:
            return self._send(conn, "m11", "m21", "m20", "m10")
        if number == OUTPUT_PARAM:
            mode = self.params.get(OUTPUT_PARAM, 0)
            if mode in (BACKLIGHT_OFF, BACKLIGHT_ON):
                with self.plant.lock:
                    self.plant.world.io["backlight"] = mode == BACKLIGHT_ON
            return self._send(conn, "m11", "m21", "m20", "m10")
        job = self._job(number)
        if job is None:
            return self._send(conn, "m12", "m22")
        rule = self.faults.check("plate", text) if self.faults is not None else None
        return self._start(conn, number, job,
                           servo_error=rule is not None and rule.kind == "servo_timeout")

    def _value_ok(self, param: int, value: int | None) -> bool:
        if value is None:
            return False
        c = self.cmds
        if param == c.purge:
            lo, hi = PURGE_TURNS
        elif param in SPEED_PARAMS:
            lo, hi = SPEED
        elif param == OUTPUT_PARAM:
            lo, hi = 0, 5
        elif param in (c.feed_forward, c.feed_backward, c.flip_forward, c.flip_backward,
                       c.flip, c.dispense):
            lo, hi = TURNS
        else:
            return False
        return lo <= value <= hi

    def _job(self, number: int):
        c, reps = self.cmds, self.params.get(number, 1)
        p = self.plate
        table = {c.feed_forward: lambda: p.feed(1, reps), c.feed_backward: lambda: p.feed(-1, reps),
                 c.flip_forward: lambda: p.flip(reps, 1), c.flip_backward: lambda: p.flip(reps, -1),
                 c.flip: lambda: p.flip(reps), c.dispense: lambda: p.dispense(reps),
                 c.purge: lambda: p.purge(reps)}
        return table.get(number)

    def _start(self, conn: socket.socket, number: int, make, init: bool = False,
               servo_error: bool = False) -> None:
        self.busy = True
        self.actions += 0 if init else 1
        n = self.actions
        self._send(conn, "m11", "m21")
        with self.plant.lock:
            job = make()

        def finish() -> None:
            self.plant.wait(job, timeout=60.0)
            self.busy = False
            if not job.ok:
                self._send(conn, "m17", "m27")
                return
            if init:
                self.initialised = True
            if not init and (n == self.servo_error_at or servo_error):
                self.error_state = True
                return self._send(conn, "m20", "m13")
            if not init and n == self.no_sync_at:
                return self._send(conn, "m10", "m28")
            self._send(conn, "m20", "m10")

        threading.Thread(target=finish, name="anyfeeder-action", daemon=True).start()
