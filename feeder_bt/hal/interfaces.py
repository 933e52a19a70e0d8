"""HAL interfaces (thesis 8.2.1.3: abstract server-level base classes).

Anything that takes time returns a ``Job``; cheap reads return values. Implementations
raise the typed errors of ``feeder_bt.core.errors`` through the job.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from feeder_bt.core.errors import ConveyorFault, HalError
from feeder_bt.core.jobs import DoneJob, Job


@dataclass(frozen=True)
class Pose:
    """A pose in the robot frame (mm, degrees about z)."""

    x: float
    y: float
    z: float = 0.0
    rz: float = 0.0


@dataclass(frozen=True)
class PickTarget:
    """What the retriever asks the robot to pick: a part's pose on the belt at a latch."""

    part_id: int
    x_mm: float          # belt frame, at the latch
    y_mm: float
    angle_deg: float
    latch: int           # robot encoder count at the latch
    tracking: bool = True
    tool_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # the grip's turn from the part's angle (``PartSpec.pick``): the gripper closes at
    # angle_deg + grip_deg; the part is still placed by angle_deg
    grip_deg: float = 0.0


@dataclass
class Frame:
    """An image and the conveyor encoder latched by the same trigger."""

    image: np.ndarray    # uint8, grey
    latch: int           # conveyor controller's count (32-bit signed) at the trigger
    t: float             # clock time of the trigger
    index: int = 0


@dataclass
class PickResult:
    part_id: int
    t: float
    belt_x_mm: float = 0.0


@dataclass(frozen=True)
class Held:
    """What the robot controller says its gripper holds, asked after a reply was lost.

    The cell sends the part's id with every ``pick``; the controller keeps the id of the
    part it gripped until it lets it go, and the id of the last part it released at a
    place pose. So after a link cut at any step of a pick-and-place the cell can tell
    "picked, reply lost" from "never picked" and "placed, reply lost" from "still held"."""

    part_id: int | None = None          # the commanded part in the gripper; None: nothing
    unknown: bool = False               # something is gripped that no pick of ours gripped
    last_placed: int | None = None      # the last part released at a place pose

    @property
    def empty(self) -> bool:
        return self.part_id is None and not self.unknown


@dataclass
class IoChange:
    signal: str
    value: bool
    t: float


class Conveyor(Protocol):
    """One conveyor axis. Speeds in mm/s; distances in mm along the belt."""

    name: str

    def set_speed(self, mm_s: float) -> Job:
        """Jog at a speed (0 stops); the job ends when the speed is reached."""

    def move(self, distance_mm: float, mm_s: float) -> Job:
        """Relative move; the job ends when the move is complete."""

    def stop(self) -> Job: ...

    def shake(self, amplitude_mm: float, cycles: int) -> Job:
        """Jog back and forth to clear a jam; returns to the previous speed after."""

    def speed(self) -> float:
        """Commanded speed now (mm/s)."""

    def position(self) -> int:
        """Encoder count now (the controller's own representation)."""

    def position_age(self) -> float | None:
        """Seconds since ``position()``'s count was read from the controller; None while
        no fresh read exists (a link down). Lets a check carry a cached count forward."""

    def travelled(self, distance_mm: float) -> Job:
        """A notification: ends when the belt has moved ``distance_mm`` from now."""

    def fault(self) -> HalError | None:
        """A fault the controller reported while the belt ran (a jam: the motor stalled,
        a following error), or None. Cleared by the next motion command."""

    def servo(self, on: bool) -> Job:
        """Motor (amplifier) on or off. Only the operator's reset turns a motor back on
        after an off-on-error or the e-stop; a simulated belt has no amplifier."""


def speed_refused(conveyor: str, job: str, mm_s: float, max_mm_s: float,
                  cell_file: object = None) -> Job | None:
    """A failed ``conveyor.job`` when ``mm_s`` is above the conveyor's ``max_mm_s`` (None
    when it is within). Every conveyor, simulated or real, refuses rather than clamps, so a
    run keeps to the limits the loader checks and an over-limit command is said in one line
   . Exactly ``max_mm_s`` is allowed (``shake`` runs at it)."""
    if abs(mm_s) <= max_mm_s * (1.0 + 1e-9):
        return None
    where = f" ({cell_file})" if cell_file else ""
    return DoneJob(f"{conveyor}.{job}", error=HalError(
        f"{conveyor} conveyor: {abs(mm_s):g} mm/s commanded, above its max_mm_s "
        f"{max_mm_s:g}{where}; refused"))


def watchdog_stopped(conveyor: str, watchdog_s: float) -> ConveyorFault:
    """What a conveyor's ``fault()`` says after the Galil's host watchdog (``#WDOG`` in
    galil_programs/monitor.dmc) stopped the belts: the real driver and the simulated cell
    say it alike, so the trees recover from both the same way."""
    return ConveyorFault(f"{conveyor}: the Galil's host watchdog stopped the belts "
                         f"(the host was silent for {watchdog_s:g} s)")


class Camera(Protocol):
    def grab(self) -> Job:
        """Trigger (mirrored to the conveyor latch) and grab; result is a ``Frame``."""

    def set_exposure(self, ms: float) -> Job: ...


class Robot(Protocol):
    def pick(self, target: PickTarget) -> Job:
        """Pick a part, tracking the belt if ``target.tracking``; result ``PickResult``.

        Errors: ``MissedGrab`` (nothing held after the grip), ``EnvelopeError`` (out of
        reach by the time the robot gets there), ``ServoTimeout``.
        """

    def place(self, pose: Pose) -> Job:
        """Place the held part. Never abandoned half-way: a cancelled place lets the part go
        at the place pose and the job ends SUCCEEDED."""

    def move_to(self, pose: Pose) -> Job: ...

    def move_safe(self) -> Job:
        """Move clear of the belt and the camera's view."""

    def set_speed(self, pct: float) -> Job: ...

    def recover(self) -> Job:
        """Run the controller's recovery program and re-enable power (after a servo error)."""

    def holding(self) -> bool:
        """Cheap local view (the last reply's word); after a lost reply ask ``held()``."""

    def held(self) -> Job:
        """Ask the controller what the gripper holds; result ``Held``. On a controller
        still finishing a motion whose reply was lost, the answer comes after the motion."""


class RobotPosition(Protocol):
    """Read-only view of the robot controller, usable while the robot moves."""

    def belt_encoder(self) -> int:
        """The robot controller's count of the belt encoder (24-bit signed)."""

    def age(self) -> float | None:
        """Seconds since ``belt_encoder()`` and ``pose()`` were read; None: no fresh read."""

    def pose(self) -> Pose: ...


class DigitalIO(Protocol):
    """Named signals (the cell description maps names to controllers and bit numbers)."""

    def get(self, signal: str) -> bool: ...

    def set(self, signal: str, value: bool) -> Job: ...

    def changes(self) -> list[IoChange]:
        """Input changes since the last call (drained)."""


@dataclass(frozen=True)
class PlateStatus:
    """A plate feeder's word on itself: initialised, busy, and its fault (None: none)."""

    initialised: bool
    busy: bool
    fault: HalError | None = None


PLATE_ACTIONS = ("dispense", "feed_forward", "feed_backward", "flip", "flip_forward",
                 "purge")


class PlateFeeder(Protocol):
    """A vibratory plate with a bulk container and a backlight (an AnyFeeder-class
    feeder): the incremental presentation of thesis chapter 2. Each action is a
    job that ends when the parts are at rest on the plate."""

    def init(self) -> Job:
        """Home the drives; nothing else is accepted before it (AnyFeeder Guide, m16)."""

    def dispense(self, reps: int) -> Job:
        """Drop parts from the bulk container onto the rear of the plate."""

    def feed(self, direction: int, reps: int) -> Job:
        """Vibrate the parts forward (+1, away from the bulk) or backward (-1)."""

    def flip(self, reps: int, direction: int = 0) -> Job:
        """Throw the parts up so they land in new poses (0: in place; +-1: and feed)."""

    def purge(self, reps: int) -> Job:
        """Carry the parts on the plate back into the bulk container."""

    def reset(self) -> Job:
        """Clear a servo error or error state (AnyFeeder Guide, m13/m17: "Error must be
        reset before operation can continue")."""

    def status(self) -> PlateStatus: ...


class WorldTruth(Protocol):
    """What only a simulated cell knows: where every part really is and what really
    happened to it. The run report's accounting, the dashboard's misoriented count and the
    part server's check of a robot's PLACED read it; the trees never do, and on a real cell
    there is none (``Hal.truth`` is None). ``feeder_bt.sim.world.World`` is the one."""

    counts: dict[str, int]                 # released, landed, recirculated, misoriented, ...
    total: int                             # parts that entered the cell
    problems: list[str]                    # accounting findings, each part named
    misplaced_by_type: dict[str, int]
    placed_by_type: dict[str, int]
    pick_waited_s: float
    slid_mm: float
    broken: bool                           # the accounting found a part lost or duplicated
    robot_model: object                    # the arm as it really moves (robot.scara)
    passlog: object                        # the record of every part's pass (sim.passlog)
    horizontal: object                     # the belts' axes (their ``clamped`` counts)
    incline: object
    clock: object
    listeners: list

    def audit(self) -> None: ...

    def lost(self) -> list: ...

    def duplicated(self) -> list: ...

    def census(self) -> dict: ...


@dataclass
class Hal:
    """The whole cell as the trees see it."""

    conveyors: dict[str, Conveyor]
    robot: Robot
    robot_position: RobotPosition
    camera: Camera
    io: DigitalIO
    kind: str = "sim"
    extras: dict = field(default_factory=dict)
    plate: PlateFeeder | None = None     # a plate cell's feeder; None: belts
    # the simulated world's truth, for the report's accounting and checks only (never the
    # trees'); None on a real cell
    truth: WorldTruth | None = None

    def step(self, now: float) -> None:
        """Advance anything that runs on the clock (the simulated world) to ``now``."""

    def motors_on(self) -> None:
        """The operator's Start: a real cell's belt amplifiers go on (``SH``) only when a
        person asks, never at a connect. Nothing to do on a simulated belt."""

    def changeover(self, scenario) -> None:
        """The operator swaps the parts for another scenario's (the simulated cell refills
        its hopper; a real cell has nothing to do)."""

    def close(self) -> None:
        """Release connections and workers."""
