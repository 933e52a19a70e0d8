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
    """The AnyFeeder's command numbers (``x=N``): 1-4 are in the Adept AnyFeeder User's
    Guide Rev. B, Table 3-3; the others could not be confirmed from a public source and
    are settings to check at commissioning (docs/plate-feeders.md)."""

    feed_forward: int = 1        # Table 3-3: x=1
    feed_backward: int = 2       # Table 3-3: x=2
    flip_forward: int = 3        # Table 3-3: x=3 (feed + flip forward)
    flip_backward: int = 4       # Table 3-3: x=4
    flip: int = 5                # check at commissioning
    dispense: int = 6            # check at commissioning
    purge: int = 7               # check at commissioning
    init: int = 15               # check at commissioning
    reset: int = 16              # check at commissioning (clears a servo / error state)


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
    baud: int = 9600                     # check at commissioning
    timeout_s: float = 10.0              # a reply later than the action time + this: fault
    commands: PlateCommands = field(default_factory=PlateCommands)


@dataclass
class PlatePolicy:
    """How the plate is worked when a look finds nothing new to pick (``present.plate``).

    ``smart``: the next action from what the last frame showed (docs/plate-feeders.md);
    ``fixed``: dispense, feed forward and flip every time (the comparison)."""

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
