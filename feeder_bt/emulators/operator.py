"""The person at the emulated cell: what they do with their hands, one line at a time.

``feeder emulate cell`` reads these actions on its standard input and answers each with one
line (``ok ...`` or ``error ...``), so commissioning (``feeder commission``, another
process) can be rehearsed as it is done on a real cell: the commissioning asks, the person
acts on the cell, then answers the commissioning.

    toggle NAME          flip input NAME (a cell io name, or CONVEYOR.forward_limit /
                         CONVEYOR.reverse_limit: a limit switch)
    press NAME           make NAME active (release NAME: inactive)
    look NAME            what the person sees of output NAME (a lamp, the vacuum)
    trigger              fire the camera trigger (the Galil latch input sees it)
    push BELT MM         move a conveyor by hand, motor off (BELT: a conveyor or axis letter)
    touch X Y            jog the robot tool with the pendant onto cell point (X, Y)
    power on|off         the robot's arm power at the front panel
    part on|off          hold a part against the gripper (the grip sensor), or take it away
    marker X Y           put the round marker on the belt at cell (X, Y); marker off
    target X Y DEG       lay the calibration target on the belt at that pose; target off
    help                 this list
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from feeder_bt.calibration.camera import Target, TargetPose
from feeder_bt.emulators.camera_server import CameraScene
from feeder_bt.sim.realtime import Plant

HELP = ("actions: toggle NAME | press NAME | release NAME | look NAME | trigger | "
        "push BELT MM | touch X Y | power on|off | part on|off | marker X Y | marker off | "
        "target X Y DEG | target off | help")
LIMITS = {"forward_limit": True, "reverse_limit": False}
PUSH_MM_S = 50.0             # how fast a hand pushes a belt


class ActionError(Exception):
    """A line the operator cannot act on: answered with one ``error`` line."""


class Operator:
    """Acts on the plant and the emulators; ``handle(line)`` returns the one-line answer."""

    def __init__(self, plant: Plant, galil: Any = None, adept: Any = None,
                 scene: CameraScene | None = None, target: Target | None = None) -> None:
        self.plant, self.galil, self.adept, self.scene = plant, galil, adept, scene
        self.target = target
        self.part_held = False
        self._verbs: dict[str, Callable[[list[str]], str]] = {
            "toggle": lambda a: self._input(a, None), "press": lambda a: self._input(a, True),
            "release": lambda a: self._input(a, False), "look": self._look,
            "trigger": self._trigger, "push": self._push, "touch": self._touch,
            "power": self._power, "part": self._part, "marker": self._marker,
            "target": self._target, "help": lambda a: HELP}

    def handle(self, line: str) -> str | None:
        """One action; None for a blank or comment line (nothing to answer)."""
        words = line.split("#", 1)[0].split()
        if not words:
            return None
        verb = self._verbs.get(words[0].lower())
        if verb is None:
            return f"error: unknown action {words[0]!r} (help lists them)"
        try:
            return f"ok {verb(words[1:])}".rstrip()
        except ActionError as e:
            return f"error: {words[0]}: {e}"

    # ------------------------------------------------------------------ inputs
    def _input(self, args: list[str], value: bool | None) -> str:
        name = _one(args, "NAME")
        conv, _, limit = name.partition(".")
        if limit in LIMITS:
            return self._limit(conv, LIMITS[limit], value)
        sig = self.plant.cell.io.get(name)
        if sig is None or sig.dir != "in":
            inputs = sorted(n for n, s in self.plant.cell.io.items() if s.dir == "in")
            raise ActionError(f"no input {name!r} in the cell (inputs: {', '.join(inputs) or 'none'}"
                              "; limit switches: CONVEYOR.forward_limit|reverse_limit)")
        now = (not self.plant.signal(name)) if value is None else value
        self.plant.set_signal(name, now)
        return f"{name} {'active' if now else 'inactive'}"

    def _limit(self, conv: str, forward: bool, value: bool | None) -> str:
        if self.galil is None:
            raise ActionError("no Galil emulator")
        letter = self._letter(conv)
        with self.galil.lock:
            st = self.galil.axes[letter]
            attr = "lf" if forward else "lr"
            active = getattr(st, attr) == 0
        now = (not active) if value is None else value
        if now and not active:
            self.galil.trip_limit(letter, forward=forward)
        elif not now:
            with self.galil.lock:
                setattr(st, attr, 1)
        which = "forward" if forward else "reverse"
        return f"{conv} {which} limit {'active' if now else 'inactive'}"

    def _letter(self, name: str) -> str:
        axes = self.plant.cell.galil.axes
        if name in axes:
            return axes[name].upper()
        if name.upper() in (a.upper() for a in axes.values()):
            return name.upper()
        raise ActionError(f"no conveyor {name!r} (conveyors: {', '.join(axes)})")

    # ------------------------------------------------------------------ looking
    def _look(self, args: list[str]) -> str:
        name = _one(args, "NAME")
        sig = self.plant.cell.io.get(name)
        if sig is None or sig.dir == "in":
            outs = sorted(n for n, s in self.plant.cell.io.items() if s.dir != "in")
            raise ActionError(f"no output {name!r} in the cell (outputs: {', '.join(outs)})")
        return f"{name} {'on' if self.plant.signal(name) else 'off'}"

    # ------------------------------------------------------------------ belts, trigger
    def _trigger(self, args: list[str]) -> str:
        t = self.plant.trigger()
        return f"trigger at t={t:.3f}"

    def _push(self, args: list[str]) -> str:
        if len(args) != 2:
            raise ActionError("expected: push BELT MM")
        letter = self._letter(args[0])
        mm = _number(args[1], "MM")
        if self.galil is not None:
            with self.galil.lock:
                if self.galil.axes[letter].servo:
                    raise ActionError(f"the motor of axis {letter} is on: it holds the belt "
                                      "(turn it off first)")
        job_end = self.plant.move(letter, mm * self.plant.cpm, PUSH_MM_S * self.plant.cpm)
        _sleep_until(self.plant, job_end)
        return f"pushed {args[0]} {mm:g} mm"

    # ------------------------------------------------------------------ robot
    def _touch(self, args: list[str]) -> str:
        if len(args) != 2:
            raise ActionError("expected: touch X Y")
        x, y = _number(args[0], "X"), _number(args[1], "Y")
        jog = getattr(self.adept, "pendant_to_cell", None)
        if jog is None:
            raise ActionError("this V+ emulator has no pendant (AdeptEmulator.pendant_to_cell)")
        jog(x, y)
        return f"tool at cell ({x:g}, {y:g})"

    def _power(self, args: list[str]) -> str:
        if self.adept is None:
            raise ActionError("no V+ emulator")
        word = _one(args, "on|off").lower()
        if word not in ("on", "off"):
            raise ActionError(f"expected on or off, got {word!r}")
        setter = getattr(self.adept, "set_power", None)
        if setter is not None:
            on = setter(word == "on")
        elif word == "on":
            on = self.adept.operator_reset()
        else:
            self.adept.power = False
            on = False
        return f"arm power {'on' if on else 'off (refused: e-stop active?)'}"

    def _grip_signals(self) -> tuple[str | None, str | None]:
        """The cell's grip sensor input and vacuum output (names containing grip, vacuum)."""
        io = self.plant.cell.io
        sensor = next((n for n, s in io.items() if s.dir == "in" and "grip" in n), None)
        vacuum = next((n for n, s in io.items() if s.dir != "in" and "vacuum" in n), None)
        return sensor, vacuum

    def _part(self, args: list[str]) -> str:
        word = _one(args, "on|off").lower()
        if word not in ("on", "off"):
            raise ActionError(f"expected on or off, got {word!r}")
        sensor, _ = self._grip_signals()
        if sensor is None:
            raise ActionError("the cell names no grip sensor input (io.grip: {controller: "
                              "adept, bit: 3, dir: in})")
        self.part_held = word == "on"
        self.sync_grip()
        return f"part {'held to' if self.part_held else 'away from'} the gripper"

    def sync_grip(self) -> None:
        """The grip sensor (a cell input named ``grip``, the V+ programs' vacuum switch)
        reads what the cup holds: while the person holds a part to it, whether the vacuum
        is on; otherwise whether the simulated gripper holds a part (a run's picks). Called
        every few ms by the emulator."""
        sensor, vacuum = self._grip_signals()
        if sensor is None:
            return
        if self.part_held:
            want = vacuum is not None and self.plant.signal(vacuum)
        else:
            with self.plant.lock:
                want = self.plant.world.gripper is not None
        if self.plant.signal(sensor) != want:
            self.plant.set_signal(sensor, want)

    # ------------------------------------------------------------------ camera
    def _marker(self, args: list[str]) -> str:
        scene = self._scene()
        if args == ["off"]:
            scene.take_marker()
            return "marker taken away"
        if len(args) != 2:
            raise ActionError("expected: marker X Y, or marker off")
        x, y = _number(args[0], "X"), _number(args[1], "Y")
        scene.put_marker(x, y)
        return f"marker at cell ({x:g}, {y:g})"

    def _target(self, args: list[str]) -> str:
        scene = self._scene()
        if args == ["off"]:
            scene.lay_target(None)
            return "target taken away"
        if len(args) != 3:
            raise ActionError("expected: target X Y DEG, or target off")
        pose = TargetPose(_number(args[0], "X"), _number(args[1], "Y"), _number(args[2], "DEG"))
        scene.lay_target(self.target or Target(), pose)
        return f"target at cell ({pose.x_mm:g}, {pose.y_mm:g}), {pose.angle_deg:g} deg"

    def _scene(self) -> CameraScene:
        if self.scene is None:
            raise ActionError("no emulated camera")
        return self.scene


def _one(args: list[str], what: str) -> str:
    if len(args) != 1:
        raise ActionError(f"expected one {what}")
    return args[0]


def _number(text: str, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ActionError(f"{what}: expected a number, got {text!r}") from None


def _sleep_until(plant: Plant, t: float) -> None:
    """Wait (wall time) until the plant's clock reaches ``t``: a push takes its time."""
    import time
    while plant.now() < t:
        time.sleep(min(0.05, max(plant.clock.wall_delay(t), 0.001)))
