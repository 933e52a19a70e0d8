"""An AnyFeeder emulator over the simulated plate: ``feeder emulate plate``.

It listens on 127.0.0.1 and passes the feeder's bytes raw, as a serial-to-Ethernet bridge
in a plant would, so the driver reaches it with ``socket://127.0.0.1:PORT``. At least as
permissive as the manuals (Adept AnyFeeder User's Guide Rev. B 3.6, Rev. A pp. 30-34) and
the public driver SHOP4CF/anyfeeder_connector, and as strict where they are: commands 1-8
(8: heavy dispense), 15 stop, 16 init, 30 error reset, 31 firmware restart; repetitions
``ab[1..8]`` (purge 1...127), speeds ``ab[17..23]`` 1...10, outputs ``ab[27]`` 0...5. A line
that is not the syntax, an unknown command or a value out of range gets ``m12``/``m22``
("Invalid command"); any command before the init ``m16``/``m26``; after a servo error
(``m13``) every command but the reset and the restart ``m17``/``m27``. A line may end CR LF
(the LF is ignored). An action answers ``m11`` and ``m21``, and ``m10`` and ``m20`` when
the simulated plate is at rest (Table 3-6).

What the manuals do not say, chosen here and checked at commissioning
(docs/plate-feeders.md): a command while an action runs is refused with ``m12``/``m22``,
except the stop, which is answered when the motion ends; the error reset homes the plate
(anyfeeder_connector: "Reset error status and move AnyFeeder to home position").

Switches, for tests and rehearsals: ``echo`` (each line is echoed before the motor codes,
as anyfeeder_connector expects), ``motor_gap_s`` (motor 2 reports this long after motor
1), ``servo_error_at`` (the Nth action ends ``m13``), ``no_sync_at`` (the Nth action ends
``m10``, ``m28``), ``late_error_at`` (in the Nth action motor 2 never starts: ``m11``,
``m10``, and ``late_s`` later ``late_code``, no sync; nothing moves); in a whole emulated run, a fault plan's ``servo_timeout`` rule for
controller ``plate`` (``emulators.faults``; its ``command`` matched against the action's
line, e.g. ``x=1``) ends the matching action ``m13``.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable

from feeder_bt.core.jobs import Job
from feeder_bt.core.plate_model import PlateCommands
from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.emulators.line_server import LineServer
from feeder_bt.hal.anyfeeder.protocol import (
    BACKLIGHT_OFF,
    BACKLIGHT_ON,
    CR,
    OUTPUT_PARAM,
    SPEED_PARAMS,
    ProtocolError,
    param_range,
    parse_command,
)
from feeder_bt.sim.realtime import Plant

PLATE_FAULTS = ("servo_timeout",)    # the fault plan's kinds this emulator acts on
DEFAULTS = {1: 3, 2: 3}              # Table 3-7: ab[1]=3, ab[2]=3; the rest: 1 here
STANDARD = ("m11", "m21", "m20", "m10")


class AnyFeederEmulator(LineServer):
    """One client at a time on ``port`` (0: any free port, see ``.port``); a newer one
    takes the line, as on the feeder's serial port, which hears whoever writes."""

    terminator = CR
    thread_name = "anyfeeder-emulator"
    displace = True

    def __init__(self, plant: Plant, host: str = "127.0.0.1", port: int = 0,
                 servo_error_at: int | None = None, no_sync_at: int | None = None,
                 faults: FaultPlan | None = None, echo: bool = False,
                 motor_gap_s: float = 0.0, late_error_at: int | None = None,
                 late_code: str = "m28", late_s: float = 0.2) -> None:
        self.plant = plant
        self.plate = plant.hal.plate
        self.cmds: PlateCommands = plant.cell.plate.commands
        self.params: dict[int, int] = dict(DEFAULTS)
        self.initialised = False
        self.error_state = False
        self.busy = False
        self.actions = 0
        self.servo_error_at, self.no_sync_at = servo_error_at, no_sync_at
        self.echo, self.motor_gap_s = echo, motor_gap_s
        self.late_error_at, self.late_code, self.late_s = late_error_at, late_code, late_s
        self.faults = faults            # controller "plate": servo_timeout ends it m13
        for rule in faults.rules if faults is not None else ():
            if rule.controller == "plate" and rule.kind not in PLATE_FAULTS:
                raise ValueError(f"the AnyFeeder emulator cannot inject {rule.kind!r}; "
                                 f"plate faults: {', '.join(PLATE_FAULTS)}")
        self.lines: list[str] = []                      # what it received, for tests
        self.done: list[tuple[str, int]] = []           # actions run: (name, repetitions)
        self.overlaps = 0                               # commands refused while busy
        self._send_lock = threading.Lock()
        super().__init__(host, port)

    def on_line(self, conn: socket.socket, line: bytes) -> None:
        text = line.decode("ascii", "replace").strip("\n")     # CR LF: the LF ignored
        if self.echo:
            self._send(conn, text)
        self._line(conn, text)

    def _send(self, conn: socket.socket, *codes: str) -> None:
        with self._send_lock:
            try:
                conn.sendall(b"".join(c.encode("ascii") + CR for c in codes))
            except OSError:
                pass

    def names(self) -> dict[int, str]:
        """Command number -> the action's name (the person's ``look``)."""
        c = self.cmds
        return {c.feed_forward: "feed_forward", c.feed_backward: "feed_backward",
                c.flip_forward: "flip_forward", c.flip_backward: "flip_backward",
                c.flip: "flip", c.dispense: "dispense", c.purge: "purge",
                c.heavy_dispense: "heavy_dispense", c.init: "init", c.reset: "reset"}

    # ------------------------------------------------------------------ the feeder
    def _line(self, conn: socket.socket, text: str) -> None:
        self.lines.append(text)
        try:
            cmd = parse_command(text)
        except ProtocolError:
            return self._send(conn, "m12", "m22")
        if self.busy:
            if cmd.execute == self.cmds.stop and cmd.param is None:
                return None                 # answered when the running motion ends
            self.overlaps += 1
            return self._send(conn, "m12", "m22")
        if cmd.param is not None and not self._value_ok(cmd.param, cmd.value):
            return self._send(conn, "m12", "m22")
        if cmd.execute is None:                      # a parameter set: no response
            self.params[cmd.param] = cmd.value
            return None
        number = cmd.execute
        if cmd.param is not None:
            self.params[cmd.param] = cmd.value
        if number == self.cmds.restart:              # the firmware again: defaults
            self.params = dict(DEFAULTS)
            self.initialised = self.error_state = False
            return self._send(conn, *STANDARD)
        if number == self.cmds.reset:
            self.error_state = False
            return self._start(conn, "reset", lambda: self.plate.init(), home=True)
        if self.error_state:
            return self._send(conn, "m17", "m27")
        if number == self.cmds.init:
            return self._start(conn, "init", lambda: self.plate.init(), home=True)
        if not self.initialised:
            return self._send(conn, "m16", "m26")
        if number == self.cmds.stop or number in SPEED_PARAMS:
            return self._send(conn, *STANDARD)
        if number == OUTPUT_PARAM:
            mode = self.params.get(OUTPUT_PARAM, 0)
            if mode in (BACKLIGHT_OFF, BACKLIGHT_ON):
                with self.plant.lock:
                    self.plant.world.io["backlight"] = mode == BACKLIGHT_ON
            return self._send(conn, *STANDARD)
        job = self._job(number)
        if job is None:
            return self._send(conn, "m12", "m22")
        rule = self.faults.check("plate", text) if self.faults is not None else None
        return self._start(conn, self.names()[number], job,
                           servo_error=rule is not None and rule.kind == "servo_timeout",
                           reps=self.params.get(number, 1))

    def _value_ok(self, param: int, value: int | None) -> bool:
        span = param_range(param)
        return value is not None and span is not None and span[0] <= value <= span[1]

    def _job(self, number: int) -> Callable[[], Job] | None:
        c, reps = self.cmds, self.params.get(number, 1)
        p = self.plate
        # heavy dispense: no figures published; the simulated plate dispenses as for x=6
        table = {c.feed_forward: lambda: p.feed(1, reps), c.feed_backward: lambda: p.feed(-1, reps),
                 c.flip_forward: lambda: p.flip(reps, 1), c.flip_backward: lambda: p.flip(reps, -1),
                 c.flip: lambda: p.flip(reps), c.dispense: lambda: p.dispense(reps),
                 c.heavy_dispense: lambda: p.dispense(min(reps * 2, 10)),
                 c.purge: lambda: p.purge(reps)}
        return table.get(number)

    def _start(self, conn: socket.socket, name: str, make: Callable[[], Job],
               home: bool = False, servo_error: bool = False, reps: int = 0) -> None:
        self.busy = True
        self.actions += 0 if home else 1
        n = self.actions
        gap = self.motor_gap_s
        late = not home and n == self.late_error_at     # motor 2 never starts: no m21
        self._send(conn, "m11")
        if gap <= 0 and not late:
            self._send(conn, "m21")
        job = None
        if not late:                                    # a dispense that never happened
            with self.plant.lock:
                job = make()
        spec = self.plant.cell.plate

        def finish() -> None:
            if gap > 0 and not late:
                time.sleep(gap)
                self._send(conn, "m21")
            if job is None:
                time.sleep(max(reps, 1) * spec.rep_s + spec.settle_s)
                first, second = "m10", self.late_code
            elif not self.plant.wait(job, timeout=60.0) or not job.ok:
                first, second = "m17", "m27"
            elif home:
                self.initialised = True
                first, second = "m10", "m20"
            elif n == self.servo_error_at or servo_error:
                self.error_state = True
                first, second = "m13", "m20"
            elif n == self.no_sync_at:
                first, second = "m10", "m28"
            else:
                first, second = "m10", "m20"
            if job is not None and job.ok and not home:
                self.done.append((name, reps))
            elif home and first == "m10":
                self.done.append((name, 0))
            if gap <= 0 and (first, second) == ("m10", "m20"):
                first, second = "m20", "m10"          # Table 3-6's order (either is)
            self._send(conn, first)
            time.sleep(self.late_s if late else gap)
            self.busy = False                 # free before its last word: a driver may
            self._send(conn, second)          # write the next command at once

        threading.Thread(target=finish, name="anyfeeder-action", daemon=True).start()

    def look(self) -> str:
        """What a person at the plate saw last (the rehearsal's eyes)."""
        if not self.done:
            return "nothing moved yet"
        name, reps = self.done[-1]
        return f"last {name} x{reps}" if reps else f"last {name}"


class PlateOperator:
    """The person at an emulated plate, one action a line on ``feeder emulate plate``'s
    standard input, each answered with one line: ``look`` says what the plate did last
    (what a person at a real plate sees), so ``feeder commission plate`` can be rehearsed
    with a person's eyes."""

    def __init__(self, emulator: AnyFeederEmulator) -> None:
        self.emu = emulator

    def handle(self, line: str) -> str | None:
        words = line.split()
        if not words:
            return None
        if words[0] == "help":
            return "ok actions: look (what the plate did last), help"
        if words[0] == "look":
            return "ok " + self.emu.look()
        return f"error: unknown action {words[0]!r}; try help"
