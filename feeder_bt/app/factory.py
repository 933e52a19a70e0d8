"""Which HAL a run uses: the simulated cell, the emulators, or a real cell.

A scenario runs unchanged on all three; only the cell description (ports, addresses,
calibration) and ``--hal`` differ. ``emulated`` starts the Galil and Adept emulators on
loopback, backed by the simulated cell in real time, and talks to them through the same
drivers a real cell uses.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from feeder_bt.core.clock import Clock, RealClock, SimClock
from feeder_bt.core.errors import ConfigError, HalError
from feeder_bt.core.jobs import DoneJob, Job
from feeder_bt.core.model import CellSpec, Scenario, belt_window
from feeder_bt.hal.interfaces import Hal, IoChange

HAL_KINDS = ("sim", "emulated", "real")
PROGRAMS_DIR = Path(__file__).resolve().parents[2] / "galil_programs"


class CellIO:
    """One numbering for all controllers: the cell description's signal names, each on a
    controller's bit (thesis: the I/O server and the Galil's inputs behind one interface)."""

    def __init__(self, cell: CellSpec, controllers: dict[str, object]) -> None:
        self.signals = cell.io
        self.controllers = controllers
        self.by_bit = {(s.controller, s.bit): name for name, s in cell.io.items()}
        for name, sig in cell.io.items():
            if sig.controller not in controllers:
                raise ConfigError(f"signal {name!r} is on controller {sig.controller!r}; "
                                  f"one of: {', '.join(controllers)}", key=f"io.{name}")

    def _addr(self, signal: str):
        """How a controller's I/O object names a signal: the Galil's by name, the V+
        servers' by bit number."""
        sig = self.signals[signal]
        return sig.bit if sig.controller == "adept" else signal

    def get(self, signal: str) -> bool:
        sig = self.signals.get(signal)
        if sig is None:
            return False
        return bool(self.controllers[sig.controller].get(self._addr(signal)))

    def set(self, signal: str, value: bool) -> Job:
        sig = self.signals.get(signal)
        if sig is None:
            return DoneJob(f"io.set({signal})", error=HalError(f"unknown signal {signal!r}"))
        if sig.dir != "out":
            return DoneJob(f"io.set({signal})",
                           error=HalError(f"signal {signal!r} is an input; it cannot be set"))
        return self.controllers[sig.controller].set(self._addr(signal), value)

    def changes(self) -> list[IoChange]:
        out: list[IoChange] = []
        for ctrl_name, ctrl in self.controllers.items():
            for c in ctrl.changes():
                if isinstance(c, IoChange):
                    out.append(c)
                else:                       # (bit, value, t) from the V+ notify server
                    bit, value, t = c
                    name = self.by_bit.get((ctrl_name, bit))
                    if name is not None:
                        out.append(IoChange(name, bool(value), t))
        return sorted(out, key=lambda c: c.t)


class DriverHal(Hal):
    """The cell behind the Galil and Adept drivers (a real cell or the emulators)."""

    closers: list

    def step(self, now: float) -> None:
        pass

    def motors_on(self) -> None:
        """``SH`` of every conveyor axis (it also clears a Galil card fault): the operator
        pressed Start. The jobs run on the Galil worker ahead of the set-up's motions."""
        for conv in self.conveyors.values():
            conv.servo(True)

    def changeover(self, scenario: Scenario) -> None:
        plant = self.extras.get("plant")
        if plant is not None:         # the emulated cell refills its hopper like the sim
            plant.changeover(scenario)

    def links(self) -> dict[str, Any]:
        """What the links to the controllers went through: reconnects per controller and
        the Galil watchdog's stops found after them (the run report's ``reconnects`` and
        ``watchdog_stops``), so a real cell's outages leave a trace as the simulated ones do."""
        galil, adept = self.extras.get("galil"), self.extras.get("adept")
        out: dict[str, Any] = {"reconnects": {}}
        if galil is not None:
            out["reconnects"]["galil"] = max(galil.connects - 1, 0)
            out["watchdog_stops"] = galil.watchdog_stops
        if adept is not None:
            out["reconnects"]["adept"] = sum(max(c.link.connects - 1, 0)
                                             for c in adept.clients.values())
        return out

    def close(self) -> None:
        for close in reversed(self.closers):
            try:
                close()
            except Exception:          # noqa: BLE001 - closing must reach every device
                pass


def adept_estop(cell: CellSpec) -> int | None:
    """The e-stop input the V+ motion server watches (ESTOP), from the cell's ``io.estop``
    on the Adept controller: negative when the input is active low; None if not wired."""
    from feeder_bt.hal.adept.protocol import estop_signal
    sig = cell.io.get("estop")
    if sig is None or sig.controller != "adept" or sig.dir != "in":
        return None
    return estop_signal(sig.bit, sig.active_low)


def wire_line_trigger(cell: CellSpec, source: object, io: CellIO) -> None:
    """A line-triggered pylon camera whose pulse the cell fires: ``camera.pylon.
    trigger_signal`` set and cleared once per grab, on the camera's worker (the output is
    wired to the camera's line and to the Galil latch input, docs/real-cell.md)."""
    from feeder_bt.hal.camera.latched import wait_job
    signal = cell.camera.pylon.trigger_signal
    if signal is None or not hasattr(source, "line_pulse") or source.line_pulse is not None:
        return
    timeout = cell.galil.timeout_s + 1.0

    def pulse() -> None:
        wait_job(io.set(signal, True), timeout, f"setting {signal}")
        wait_job(io.set(signal, False), timeout, f"clearing {signal}")
    source.line_pulse = pulse


def connect_drivers(cell: CellSpec, clock: Clock, source=None, kind: str = "real") -> DriverHal:
    """Open the drivers of a cell: Galil conveyors and I/O, V+ robot, latched camera."""
    from feeder_bt.hal.adept import AdeptController
    from feeder_bt.hal.camera import LatchedCamera, open_source
    from feeder_bt.hal.camera.latched import grab_timeout_s
    from feeder_bt.hal.galil import make_galil

    closers: list = []
    try:
        galil, conveyors, galil_io = make_galil(cell, clock, PROGRAMS_DIR)
        closers.append(galil.close)
        adept = AdeptController(cell.adept, clock, inputs=[
            s.bit for s in cell.io.values() if s.controller == "adept" and s.dir == "in"],
            robot=cell.robot, estop=adept_estop(cell),
            counts_per_mm=cell.encoder.counts_per_mm, window=belt_window(cell))
        closers.append(adept.close)
        latch_name = next((n for n, a in cell.galil.axes.items()
                           if a.upper() == cell.galil.latch_axis.upper()), "horizontal")
        # frames of the cell's size are checked where the camera is set to it (a pylon
        # camera, the emulated one); a stream or recorded images keep their own
        sized = kind == "emulated" or cell.camera.source.startswith("pylon:")
        camera = LatchedCamera(source if source is not None
                               else open_source(cell.camera.source, cell.camera),
                               clock, latch=conveyors[latch_name],
                               grab_timeout_s=grab_timeout_s(cell.camera),
                               size=(cell.camera.width_px, cell.camera.height_px)
                               if sized else None)
        closers.append(camera.close)
        io = CellIO(cell, {"galil": galil_io, "adept": adept.io})
        wire_line_trigger(cell, camera.source, io)
        plate = None
        if cell.presentation == "plate":    # an AnyFeeder on its serial line
            from feeder_bt.hal.anyfeeder.driver import AnyFeeder
            plate = AnyFeeder(cell.plate, clock)
            closers.append(plate.close)
    except BaseException:
        for close in reversed(closers):
            close()
        raise
    hal = DriverHal(conveyors=conveyors, robot=adept.robot, robot_position=adept.position,
                    camera=camera, io=io, kind=kind, plate=plate)
    hal.closers = closers
    hal.extras.update(galil=galil, adept=adept)
    return hal


def make_hal(kind: str, scenario: Scenario, cell: CellSpec, seed: int,
             world: CellSpec | None = None) -> tuple[Hal, Clock]:
    """The HAL and the clock for a run. ``world`` is the simulated cell's truth (a world
    file laid over the cell file, ``config/world.py``); None: the cell file's figures serve
    the world too. The controller is built from ``cell`` alone, by the caller."""
    truth = world if world is not None else cell
    if kind == "sim" and cell.presentation == "plate":
        from feeder_bt.sim.plate import make_plate_sim_hal
        clock = SimClock()
        return make_plate_sim_hal(scenario, truth, clock, seed), clock
    if kind == "sim":
        from feeder_bt.sim.devices import make_sim_hal
        clock = SimClock()
        return make_sim_hal(scenario, truth, clock, seed), clock
    if kind == "real":
        if cell.hal != "real":
            raise ConfigError(f"{cell.path}: describes a {cell.hal} cell (hal: {cell.hal}); "
                              "--hal real needs a real cell's description with its ports and "
                              "calibration files (start from cells/real_cell.yaml)", key="hal")
        clock = RealClock()
        return connect_drivers(cell, clock), clock
    if kind == "emulated":
        return start_emulated(scenario, cell, seed, world=world)
    raise ConfigError(f"unknown HAL {kind!r}; one of: {', '.join(HAL_KINDS)}", key="hal")


def start_emulated(scenario: Scenario, cell: CellSpec, seed: int,
                   faults=None, plate_options: dict | None = None,
                   world: CellSpec | None = None) -> tuple[Hal, Clock]:
    """Emulators on loopback over the simulated cell in real time, and the real drivers;
    ``plate_options`` go to the AnyFeeder emulator (echo, motor gap, a late code);
    ``world`` is the simulated cell's truth (None: the cell's figures)."""
    from feeder_bt.emulators.adept import AdeptEmulator
    from feeder_bt.emulators.camera import PlantCameraSource
    from feeder_bt.emulators.galil.emulator import GalilEmulator
    from feeder_bt.sim.realtime import Plant

    plant = Plant(scenario, world if world is not None else cell, seed).start()
    galil = GalilEmulator(plant, faults=faults).start()
    adept = AdeptEmulator(plant, faults=faults).start()
    ports = adept.ports
    plate_emu = None
    if cell.presentation == "plate":        # the AnyFeeder emulator over the plate
        from feeder_bt.emulators.anyfeeder import AnyFeederEmulator
        plate_emu = AnyFeederEmulator(plant, faults=faults, **(plate_options or {})).start()
        cell = dataclasses.replace(cell, plate=dataclasses.replace(
            cell.plate, url=f"socket://127.0.0.1:{plate_emu.port}"))
    wired = dataclasses.replace(
        cell,
        galil=dataclasses.replace(cell.galil, url=f"socket://127.0.0.1:{galil.port}"),
        adept=dataclasses.replace(cell.adept, host="127.0.0.1", motion_port=ports["motion"],
                                  position_port=ports["position"], io_port=ports["io"],
                                  notify_port=ports["notify"]))
    clock = RealClock()
    source = None
    try:
        if cell.camera.source.startswith("pylon:"):    # through pylon's camera emulator
            from feeder_bt.emulators.pylon_camera import PylonPlantCamera
            source = PylonPlantCamera(plant, cell.camera, faults=faults)
        else:
            source = PlantCameraSource(plant)
        hal = connect_drivers(wired, clock, source=source, kind="emulated")
    except BaseException:
        if source is not None:
            source.close()
        galil.stop()
        adept.stop()
        if plate_emu is not None:
            plate_emu.stop()
        plant.stop()
        raise
    hal.closers[:0] = [plant.stop, galil.stop, adept.stop]    # closed last, after drivers
    if plate_emu is not None:
        hal.closers.insert(1, plate_emu.stop)
        hal.extras["plate_emulator"] = plate_emu
    hal.extras.update(plant=plant, galil_emulator=galil, adept_emulator=adept)
    hal.truth = plant.world        # for the report's accounting only; the trees never read it
    return hal, clock
