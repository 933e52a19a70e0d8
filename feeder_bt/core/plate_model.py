"""What a vibratory-plate cell and a plate scenario add to the YAML.

A cell chooses its presentation kind with ``presentation: plate`` and describes the plate
(``plate:``); a scenario chooses how the plate is worked (``present.plate:``: smart feeding
or a fixed cycle, and the thresholds smart feeding decides by). Every figure's source or
assumption is in docs/plate-feeders.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class PlateCommands:
    """The AnyFeeder's command numbers (``x=N``). 1-4: the Adept AnyFeeder User's Guide
    Rev. B, Table 3-3; 5-8: Rev. A p. 31; 1-7, 15, 16, 30, 31: the public ROS 2 driver
    SHOP4CF/anyfeeder_connector (``executeCommand``), used on SXM and SX feeders. Cell
    settings all the same: ``feeder commission plate`` jogs each (docs/plate-feeders.md)."""

    feed_forward: int = 1        # Table 3-3: x=1
    feed_backward: int = 2       # Table 3-3: x=2
    flip_forward: int = 3        # Table 3-3: x=3 (feed + flip forward)
    flip_backward: int = 4       # Table 3-3: x=4
    flip: int = 5                # Rev. A p. 31; anyfeeder_connector
    dispense: int = 6            # Rev. A p. 31; anyfeeder_connector
    purge: int = 7               # Rev. A p. 31; anyfeeder_connector
    heavy_dispense: int = 8      # Rev. A p. 31
    stop: int = 15               # anyfeeder_connector: Stop
    init: int = 16               # anyfeeder_connector: Initialize
    reset: int = 30              # anyfeeder_connector: ResetError
    restart: int = 31            # anyfeeder_connector: RestartFirmware (defaults again)


@dataclass
class PlateSpeeds:
    """Speeds 1...10 the driver writes after each init (``ab[N+16]=V x=N+16``: Rev. A
    p. 32 for 19-22, anyfeeder_connector for 17, 18, 23); unset: the feeder's own."""

    feed_forward: int | None = None      # ab[17]
    feed_backward: int | None = None     # ab[18]
    flip_forward: int | None = None      # ab[19]
    flip_backward: int | None = None     # ab[20]
    flip: int | None = None              # ab[21]
    dispense: int | None = None          # ab[22]
    purge: int | None = None             # ab[23]


@dataclass
class PlateRepetitions:
    """Repetitions the driver writes after each init (``ab[N]=V``, no response: Rev. A
    p. 31): what a bare ``x=N`` does. The trees' actions send their own with each command;
    these matter for heavy dispense and for anything else driving the feeder."""

    feed_forward: int | None = None      # ab[1]
    feed_backward: int | None = None     # ab[2]
    flip_forward: int | None = None      # ab[3]
    flip_backward: int | None = None     # ab[4]
    flip: int | None = None              # ab[5]
    dispense: int | None = None          # ab[6]
    purge: int | None = None             # ab[7], 1...127
    heavy_dispense: int | None = None    # ab[8]


@dataclass
class PlateSpec:
    """The plate, in the cell's frame (the camera's belt frame, mm; x is the feed
    direction, forward = away from the bulk container), and its simulated physics."""

    origin_mm: tuple[float, float] = (110.0, 155.0)   # the plate's rear-left corner
    size_mm: tuple[float, float] = (440.0, 300.0)     # along x (feed), along y
    # simulated physics (assumptions, docs/plate-feeders.md "Physics")
    feed_mm_per_rep: float = 30.0        # how far one feed repetition moves a free part
    feed_cv: float = 0.25                # part-to-part spread of that distance
    feed_jitter_mm: float = 4.0          # sideways wander per repetition (sigma)
    feed_turn_deg: float = 10.0          # turn per repetition (sigma)
    flip_prob: float = 0.8               # a flip re-draws a part's pose with this probability
    flip_scatter_mm: float = 18.0        # and throws it this far (sigma, each axis)
    dispense_per_rep: float = 4.0        # parts a dispense repetition drops from a full bulk
    bulk_nominal: int = 150              # the drop falls off below this many in the bulk
    dispense_band_mm: float = 120.0      # dispensed parts land within this of the rear edge
    purge_mm_per_rep: float = 60.0       # a purge repetition carries parts this far back
    rep_s: float = 0.35                  # one repetition's time (motion), any action
    settle_s: float = 0.30               # parts at rest this long after the motion
    init_s: float = 2.0                  # the init (homing) time
    # the serial link (a real or emulated feeder)
    url: str = ""                        # serial device or socket://HOST:PORT
    baud: int = 9600                     # anyfeeder_connector: 9600 8N1, no flow control
    timeout_s: float = 10.0              # a reply later than the action time + this: fault
    quiet_s: float = 0.05                # before each command the line must be this quiet
    echo_probe_s: float = 0.5            # at connect, how long to wait for an echo
    commands: PlateCommands = field(default_factory=PlateCommands)
    speeds: PlateSpeeds = field(default_factory=PlateSpeeds)
    repetitions: PlateRepetitions = field(default_factory=PlateRepetitions)


@dataclass
class PlatePolicy:
    """How the plate is worked when a look finds nothing new to pick (``present.plate``).

    ``smart``: the next action from what the last frame showed (docs/plate-feeders.md);
    ``fixed``: dispense, feed forward and flip on every ``fixed_every``-th look that
    found nothing new, else flip only (the comparison; 1: the full cycle every time)."""

    policy: str = "smart"                # smart | fixed
    min_parts: int = 6                   # fewer blobs than this on the plate: dispense
    crowded_parts: int = 28              # more blobs than this: purge
    flip_fraction: float = 0.4           # this share of the parts unpickable: flip
    cluster_fraction: float = 0.3        # the parts' centre this far (of the length) off
                                         # the middle: feed them back to the middle
    feed_reps: int = 3                   # Table 3-7: ab[1]=3, ab[2]=3 by default
    flip_reps: int = 1
    dispense_reps: int = 2
    purge_reps: int = 2
    fixed_every: int = 1                 # fixed: the full cycle on every Nth empty look
