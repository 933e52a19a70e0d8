"""Every blackboard key, one place, by namespace.

A leaf names the keys it uses by these constants in its ``READS``/``WRITES`` (its ports);
the cell, the view, the UI and the records read them through ``Cell.board`` by the same
constants. A key spelt twice can no longer be spelt two ways.
"""

from __future__ import annotations

from typing import Final


class SPEEDS:
    """``/speeds``: what the conveyors and the robot follow (scenario, adjuster, operator)."""

    NS: Final = "/speeds"
    HORIZONTAL: Final = "/speeds/horizontal_mm_s"
    INCLINE: Final = "/speeds/incline_pct"          # % of the horizontal speed
    ROBOT: Final = "/speeds/robot_speed_pct"
    ALL: Final = (HORIZONTAL, INCLINE, ROBOT)

    @staticmethod
    def of(name: str) -> str:
        """The key of a speed by its short name (``horizontal_mm_s``), as operators send it."""
        return f"{SPEEDS.NS}/{name}"


class PRESENT:
    """``/present``: incremental presentation's requests, and the presenter's faults."""

    REQUEST: Final = "/present/request"             # "small" | "big" | a plate action
    COMPLETED: Final = "/present/completed"         # advances done, counted
    ERROR: Final = "/present/error"
    HOLD: Final = "/present/hold"                   # locate's golden-image recovery


class LOCATE:
    """``/locate``: the last frame, what the recipe made of it, and the locator's faults."""

    FRAME: Final = "/locate/frame"
    RESULT: Final = "/locate/result"
    FOUND: Final = "/locate/found"                  # new parts in the last frame
    ERROR: Final = "/locate/error"


class RETRIEVE:
    """``/retrieve``: the part being retrieved, what the robot was told, its faults."""

    PART: Final = "/retrieve/part"
    PHASE: Final = "/retrieve/phase"                # None | "pick" | "held" | "place"
    ERROR: Final = "/retrieve/error"


class FAULTS:
    """``/faults``: what a branch cannot handle; the cell goes to FAULT with the reason."""

    NS: Final = "/faults"
    ESCALATE: Final = "/faults/escalate"


class PLATE:
    """``/plate``: a vibratory plate's look to judge and the plan chosen for it."""

    LOOK: Final = "/plate/look"
    PLAN: Final = "/plate/plan"


#: the keys every run starts with, and their first values (speeds come from the scenario)
INITIAL: Final = {
    PRESENT.REQUEST: None, PRESENT.COMPLETED: 0, RETRIEVE.PART: None,
    RETRIEVE.PHASE: None,           # what the robot was last told to do with the part
    RETRIEVE.ERROR: None,
    LOCATE.ERROR: None,             # read by the fallbacks even when no job ever failed
    PRESENT.ERROR: None,
    PRESENT.HOLD: False,            # locate's golden-image recovery holds the incline
    FAULTS.ESCALATE: None, LOCATE.FRAME: None, LOCATE.RESULT: None, LOCATE.FOUND: 0,
}

#: a plate cell's own keys (``init_plate_keys``)
PLATE_INITIAL: Final = {PLATE.LOOK: 0, PLATE.PLAN: None}
