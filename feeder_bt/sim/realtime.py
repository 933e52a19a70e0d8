"""The plant behind the emulators: the simulated cell, running in real time.

The Galil emulator, the Adept emulator and the emulated camera all act on one ``Plant``:
one simulated world on a clock that follows the wall clock, stepped by its own thread and
guarded by one lock. Each emulator speaks its controller's protocol on a socket and turns
commands into actions on the plant's simulated devices, so a run through the real drivers
feeds the same parts, with the same physics, as a run on the simulated cell.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

from feeder_bt.core.clock import Clock
from feeder_bt.core.encoder import wrap
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.devices import SimHal, make_sim_hal

STEP_S = 0.002          # how often the stepper thread advances the world (wall seconds)


class FollowClock(Clock):
    """Wall time since start, times ``rate``: the world's clock in an emulated run."""

    def __init__(self, rate: float = 1.0) -> None:
        self.rate = rate
        self._t0 = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self._t0) * self.rate

    def wall_delay(self, t: float) -> float:
        """Wall seconds until clock time ``t`` (0 if past)."""
        return max(0.0, (t - self.now()) / self.rate)

    def advance(self, seconds: float) -> None:
        """Jump ``seconds`` of clock time ahead at once (Plant.run_ahead)."""
        self._t0 -= seconds / self.rate


class Plant:
    """The simulated cell that the emulators act on. Hold ``lock`` for every access."""

    def __init__(self, scenario: Scenario, cell: CellSpec, seed: int = 1,
                 rate: float = 1.0) -> None:
        self.cell = cell
        self.clock = FollowClock(rate)
        self.seed = seed
        self.lock = threading.RLock()
        self._build(scenario)
        # the counts the belts' encoders truly give per mm (the simulator's scale error:
        # docs/simulator.md), the same the robot's belt channel counts
        self.cpm = self.world.imperfect.true_cpm
        self._trigger_listeners: list[Callable[[float], None]] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: BaseException | None = None   # an accounting error stops the plant

    def _build(self, scenario: Scenario) -> None:
        make = make_sim_hal
        if self.cell.presentation == "plate":     # a vibratory-plate cell
            from feeder_bt.sim.plate import make_plate_sim_hal as make
        self.hal: SimHal = make(scenario, self.cell, self.clock,  # type: ignore[arg-type]
                                self.seed)
        self.world = self.hal.world
        self._axes = {letter.upper(): getattr(self.world, name)
                      for name, letter in self.cell.galil.axes.items()}

    def changeover(self, scenario: Scenario) -> None:
        """The operator swaps the parts: a fresh world with the new scenario's hopper. The
        belts restart from rest at the positions they had."""
        with self.lock:
            old = self.hal
            positions = {k: a.pos(self.world.now()) for k, a in self._axes.items()}
            self._build(scenario)
            for k, axis in self._axes.items():
                axis.segments[0].p0 = positions.get(k, 0.0)
            old.close()

    # ---------------------------------------------------------------- life
    def start(self) -> Plant:
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="plant", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        self.hal.close()

    def _run(self) -> None:
        while not self._stop.wait(STEP_S):
            try:
                with self.lock:
                    self.world.step(self.clock.now())
            except BaseException as e:      # noqa: BLE001 - kept for the emulators to report
                self.error = e
                return

    # ---------------------------------------------------------------- time
    def run_ahead(self, seconds: float) -> None:
        """Let ``seconds`` of the world pass at once, as if the plant had been running
        unwatched that long: the world is event-driven (``World.step`` processes every
        event up to the time it is given, in order), so the parts are where that much real
        time would have put them. For tests whose subject begins when the belts already
        carry parts; call it while no controller moves anything."""
        with self.lock:
            self.clock.advance(seconds)
            self.world.step(self.clock.now())

    def now(self) -> float:
        with self.lock:
            return self.world.now()

    def wait(self, job: Job, timeout: float | None = None) -> bool:
        """Block the calling (emulator) thread until a simulated device's job ends."""
        done = threading.Event()
        with self.lock:
            job.add_done_callback(lambda j: done.set())
        return done.wait(timeout)

    # ---------------------------------------------------------------- Galil side
    def axis(self, letter: str) -> Axis | None:
        """The conveyor driven by Galil axis ``letter`` (None: nothing connected)."""
        return self._axes.get(letter.upper())

    def position_counts(self, letter: str, t: float | None = None) -> int:
        """Encoder count of an axis (32-bit signed, as the Galil keeps it), now or at clock
        time ``t`` (a latch captures the count at the trigger's instant)."""
        axis = self.axis(letter)
        if axis is None:
            return 0
        with self.lock:
            t = self.world.now() if t is None else t
            return wrap(self.world.imperfect.galil_counts(axis.pos(t), t),
                        self.cell.encoder.conveyor_bits)

    def velocity_counts(self, letter: str) -> float:
        axis = self.axis(letter)
        if axis is None:
            return 0.0
        with self.lock:
            return axis.vel(self.world.now()) * self.cpm

    def jog(self, letter: str, counts_s: float, accel_counts_s2: float | None = None) -> float:
        """Ramp to a jog speed; returns the clock time at which it is reached."""
        axis = self._need(letter)
        with self.lock:
            if accel_counts_s2:
                axis.accel = accel_counts_s2 / self.cpm
            return axis.jog(self.world.now(), counts_s / self.cpm)

    def move(self, letter: str, counts: float, speed_counts_s: float,
             accel_counts_s2: float | None = None) -> float:
        """Relative move; returns the clock time at which it ends."""
        axis = self._need(letter)
        with self.lock:
            if accel_counts_s2:
                axis.accel = accel_counts_s2 / self.cpm
            return axis.move(self.world.now(), counts / self.cpm, speed_counts_s / self.cpm)

    def in_motion(self, letter: str) -> bool:
        axis = self.axis(letter)
        if axis is None:
            return False
        with self.lock:
            t = self.world.now()
            return abs(axis.vel(t)) > 1e-9 or axis.settle_time() > t

    def _need(self, letter: str) -> Axis:
        axis = self.axis(letter)
        if axis is None:
            raise KeyError(f"no conveyor on Galil axis {letter}")
        return axis

    # ---------------------------------------------------------------- signals
    def signal(self, name: str) -> bool:
        with self.lock:
            return self.world.io.get(name, False)

    def set_signal(self, name: str, value: bool) -> None:
        with self.lock:
            if name in self.world.io:
                self.world.io[name] = bool(value)

    def signal_at(self, controller: str, bit: int) -> str | None:
        """The cell's name for a controller's I/O bit (the cell description's ``io:``)."""
        for name, sig in self.cell.io.items():
            if sig.controller == controller and sig.bit == bit:
                return name
        return None

    # ---------------------------------------------------------------- camera trigger
    def on_trigger(self, fn: Callable[[float], None]) -> None:
        """Call ``fn(t)`` on every camera trigger (the Galil latch input is wired to it)."""
        self._trigger_listeners.append(fn)

    def trigger(self) -> float:
        """The camera's trigger pulse: every listener sees it at the same clock time."""
        with self.lock:
            t = self.world.now()
            for fn in self._trigger_listeners:
                fn(t)
            return t
