"""An emulator of the Adept controller that runs the shipped V+ programs (``vplus/*.v2``).

As the Galil emulator runs the DMC programs, this one runs ``a_server`` and the servers
it starts through an interpreter of the V+ subset they use (``emulators/vplus/``): their
own socket code on four real loopback listeners (motion, position, I/O, I/O notify; the
programs' ports 1401-1404 map to ``ports``), their own decoding, replies and errors,
their frames, forward processing, belt tracking, traps and stops. Nothing here answers
a request: what the PC sees is what the programs do. As strict as the controller: it
runs only programs that V+ would load (``start`` runs ``vplus_check`` and refuses with
the first finding, ``FILE:LINE``).

The robot is modelled in its own world frame (base at the origin) and truly sits at
``true_base`` = (x mm, y mm, deg) in the cell frame (default: the cell description's
``robot.base_mm``, ``robot.base_deg``), which may differ from what the cell description
says: the plant judges every grip and release where the arm truly is, so poses composed
in a wrong frame miss or are refused (vplus/PROTOCOL.md, "Frames").

Fault plan (controller ``adept``): ``reject`` answers ``ERR -9005``; ``drop`` closes the
connection on receipt, before anything is done; ``drop_during`` cuts the link
``after_s`` after the request arrived, while the motion runs on (V+ does not read the
socket while it moves); ``drop_after`` cuts the link instead of sending the reply;
``stall`` holds the reply back ``stall_s``; ``servo_timeout`` makes the motion run into
something: the arm stops, *Motor stalled* (-1007), the programs' trap turns arm power
off, and every motion fails with ``-604`` until the power is on again (``RECOVER 1`` if
the cell allows it, else the operator: ``operator_reset``). An active e-stop input also
turns power off.
"""

from __future__ import annotations

import socket
from collections import Counter, deque
from pathlib import Path
from typing import Any

from feeder_bt.emulators.faults import FaultPlan
from feeder_bt.emulators.vplus.check import VPLUS_DIR, require_loadable
from feeder_bt.emulators.vplus.devices import cut
from feeder_bt.emulators.vplus.program import load_dir
from feeder_bt.emulators.vplus.runtime import Runtime
from feeder_bt.emulators.vplus.trans import Trans
from feeder_bt.sim.realtime import Plant

SERVERS = ("motion", "position", "io", "notify")
VPLUS_PORTS = {"motion": 1401, "position": 1402, "io": 1403, "notify": 1404}  # init_constants
DISPATCH = {"motion": "decode_and_do", "position": "pos.decode", "io": "io.decode"}
GRIP_SENSE = 1003            # the programs' grip.sense: the vacuum switch's input
ESTOP = "estop"              # the cell's e-stop signal


class AdeptEmulator:
    """The V+ controller over ``plant``. ``start()`` returns self; ``.ports`` maps each
    server (motion, position, io, notify) to its port; ``stop()`` ends everything."""

    def __init__(self, plant: Plant | None, host: str = "127.0.0.1",
                 ports: dict[str, int] | None = None, faults: FaultPlan | None = None,
                 programs: Path | str | None = VPLUS_DIR, belt_direction: int = 1,
                 true_base: tuple[float, float, float] | None = None) -> None:
        self.plant, self.host, self.faults = plant, host, faults
        self.checked = programs is not None      # None: run vplus/ without the checker
        self.programs_dir = Path(programs if programs is not None else VPLUS_DIR)
        self.programs = load_dir(self.programs_dir)
        self.belt_direction = belt_direction
        self.ports: dict[str, int] = {name: int((ports or {}).get(name) or 0) for name in SERVERS}
        if true_base is None and plant is not None:
            r = plant.cell.robot
            true_base = (r.base_mm[0], r.base_mm[1], r.base_deg)
        self.true_base = true_base or (0.0, 0.0, 0.0)
        self.rt: Runtime | None = None
        self._listeners: dict[str, socket.socket] = {}

    def handled(self) -> dict[str, set[str]]:
        """The verbs each request server's V+ dispatch answers."""
        return {name: set(self.programs[prog].verbs) for name, prog in DISPATCH.items()}

    # ------------------------------------------------------------------ life
    def start(self) -> AdeptEmulator:
        """Run the programs; refuses (``VplusRefused``, one line naming FILE:LINE) if V+
        would not load them."""
        if self.checked:
            require_loadable(self.programs_dir)
        assert self.plant is not None
        for name in SERVERS:
            lsock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                lsock.bind((self.host, self.ports[name]))
            except OSError:
                lsock.close()
                self.stop()
                raise
            lsock.listen(1)
            self.ports[name] = lsock.getsockname()[1]
            self._listeners[name] = lsock
        x, y, deg = self.true_base
        self.rt = Runtime(self.programs, self.plant, Trans.make(x, y, 0.0, deg),
                          {VPLUS_PORTS[n]: (n, s) for n, s in self._listeners.items()},
                          faults=self.faults, belt_direction=self.belt_direction,
                          grip_sense=GRIP_SENSE)
        self.rt.start("a_server")
        return self

    def stop(self) -> None:
        if self.rt is not None:
            self.rt.stop()
        for lsock in self._listeners.values():
            lsock.close()
        self._listeners.clear()

    def __enter__(self) -> AdeptEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def drop_clients(self) -> None:
        """Break every client connection (a network fault; the servers wait for new ones)."""
        if self.rt is not None:
            for conn in list(self.rt.conns):
                cut(conn)

    # ------------------------------------------------------------------ what tests see
    @property
    def requests(self) -> deque[tuple[str, str]]:
        return self.rt.requests if self.rt is not None else deque()

    @property
    def connections(self) -> Counter[str]:
        return self.rt.connections if self.rt is not None else Counter()

    def _global(self, name: str, default: Any = 0.0) -> Any:
        cell = self.rt.globals.get(name) if self.rt is not None else None
        return default if cell is None or cell.v is None else cell.v

    @property
    def held_id(self) -> int:
        """The V+ motion server's ``held.id`` (its record of the part it gripped)."""
        return int(self._global("held.id"))

    @held_id.setter
    def held_id(self, value: int) -> None:
        assert self.rt is not None
        self.rt.globals["held.id"].v = float(value)

    @property
    def stop_requested(self) -> bool:
        return bool(self._global("stop.req"))

    @property
    def power(self) -> bool:
        return self.rt is not None and self.rt.arm.power

    def typed(self) -> list[str]:
        """What the programs TYPEd (the controller's terminal)."""
        return list(self.rt.typed) if self.rt is not None else []

    # ------------------------------------------------------------------ the person
    def estop_active(self) -> bool:
        """The e-stop's hardware input (the V+ programs read it: estop.in); the e-stop
        circuit drops arm power."""
        assert self.plant is not None
        active = self.plant.signal(ESTOP)
        if active and self.rt is not None:
            self.rt.arm.power = False
        return active

    def operator_reset(self) -> bool:
        """The operator turns arm power on (the pendant or front panel): refused while the
        e-stop input is active. Clears nothing else: a servo fault still needs RECOVER."""
        return self.set_power(True)

    def set_power(self, on: bool) -> bool:
        """Arm power on or off at the front panel; returns whether it is on now."""
        if self.rt is None:
            return False
        if on and self.estop_active():
            return False
        with self.rt.lock:
            self.rt.arm.power = on
            if not on:
                self.rt.arm.brake()
        return self.rt.arm.power

    def pendant_to_cell(self, x_mm: float, y_mm: float) -> None:
        """The person jogs the tool with the pendant onto the physical point (x, y) of the
        cell frame (z 0): the arm ends there, in robot world from the TRUE base pose."""
        assert self.rt is not None
        x, y, deg = self.true_base
        world = Trans.make(x, y, 0.0, deg).inverse() @ Trans.make(x_mm, y_mm, 0.0, 0.0, 180.0)
        with self.rt.lock:
            self.rt.arm.set_location(world)


def serve(plant: Plant, host: str = "127.0.0.1", ports: dict[str, int] | int | None = None,
          faults: FaultPlan | None = None, **kw) -> AdeptEmulator:
    """Start the V+ emulator: ``ports`` a dict per server, or N for ports N..N+3 (motion,
    position, io, notify), or None for free ports. ``feeder emulate adept --port N``."""
    if isinstance(ports, int):
        ports = {name: ports + i for i, name in enumerate(SERVERS)}
    return AdeptEmulator(plant, host=host, ports=ports, faults=faults, **kw).start()
