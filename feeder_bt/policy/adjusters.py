"""Auto-adjusters (thesis 8.1.3): turn cell statistics into new speeds every period.

A scenario picks one by name (``adjust.algorithm``) and tunes it with ``adjust.params``.
Each class declares its parameters and defaults in ``PARAMS`` so a scenario validator can
reject a misspelt key before a run starts. The thesis's two algorithms are baselines:
``queue_proportional`` (its first attempt) and ``water_marks`` (its Figure 8-2). Both
change only the horizontal belt speed; the incline and robot speeds pass through.
``supply_queue`` (ours) controls the supply — the incline — instead; see docs/performance.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import ClassVar


@dataclass
class AdjustInputs:
    """What an adjuster may look at; counts are cumulative since the run started."""

    t: float
    queue_len: int
    horizontal_mm_s: float
    incline_pct: float
    robot_speed_pct: float
    retrieved: int
    located: int
    recirculated: int
    missed: int


@dataclass(frozen=True)
class Envelope:
    """The fastest one conveyor may be driven by an adjuster, and the parameter that sets it."""

    key: str            # the ``adjust.params`` key to blame
    conveyor: str       # "horizontal" or "incline"
    mm_s: float
    how: str            # how the speed follows from the parameter, for the message


@dataclass
class Speeds:
    """The speeds the adjust tree writes back to the blackboard."""

    horizontal_mm_s: float
    incline_pct: float
    robot_speed_pct: float


class AdjusterParamError(ValueError):
    """A bad ``adjust.params`` entry; ``key`` lets the validator point at the YAML line."""

    def __init__(self, key: str, message: str) -> None:
        self.key = key
        super().__init__(f"{key}: {message}")


ADJUSTERS: dict[str, type[Adjuster]] = {}


class Adjuster:
    """Base class: subclasses set ``NAME`` and ``PARAMS`` and are registered by name."""

    NAME: ClassVar[str] = ""
    PARAMS: ClassVar[dict[str, float]] = {}

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        if cls.NAME:
            ADJUSTERS[cls.NAME] = cls

    def __init__(self, params: Mapping[str, float] | None = None) -> None:
        values = dict(self.PARAMS)
        for key, value in (params or {}).items():
            if key not in self.PARAMS:
                known = ", ".join(sorted(self.PARAMS)) or "none"
                raise AdjusterParamError(
                    key, f"unknown parameter for adjuster {self.NAME!r} (known: {known})")
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise AdjusterParamError(key, f"must be a number, got {value!r}")
            if not math.isfinite(value):
                raise AdjusterParamError(key, f"must be finite, got {value!r}")
            values[key] = float(value)
        self.params: dict[str, float] = values
        self._check()

    def _check(self) -> None:
        """Reject parameter combinations that cannot work; subclasses extend."""

    def update(self, inp: AdjustInputs) -> Speeds:
        """Called every ``adjust.period_s`` with fresh statistics; returns speeds to apply."""
        raise NotImplementedError

    def envelope(self, incline_pct: float) -> list[Envelope]:
        """The fastest speeds this adjuster can ever command, whatever the queue does.

        The loader checks each against the cell's conveyor limits, so every adjuster runs
        under the same limits as a fixed setting. ``incline_pct`` is the
        scenario's, which adjusters of the horizontal belt keep."""
        if "max_mm_s" not in self.params:
            return []
        top = self.params["max_mm_s"]
        return [Envelope("max_mm_s", "horizontal", top, f"{top:g} mm/s"),
                Envelope("max_mm_s", "incline", top * incline_pct / 100.0,
                         f"{top:g} mm/s at present.incline_pct {incline_pct:g}")]

    @staticmethod
    def _with_horizontal(inp: AdjustInputs, horizontal_mm_s: float) -> Speeds:
        return Speeds(horizontal_mm_s, inp.incline_pct, inp.robot_speed_pct)

    def _check_range(self) -> None:
        if self.params["min_mm_s"] > self.params["max_mm_s"]:
            raise AdjusterParamError("min_mm_s", "must not exceed max_mm_s")
        if self.params["min_mm_s"] < 0:
            raise AdjusterParamError("min_mm_s", "must not be negative")

    def _clamp(self, speed: float) -> float:
        return min(max(speed, self.params["min_mm_s"]), self.params["max_mm_s"])


class NoAdjuster(Adjuster):
    """Leaves every speed alone: the control for comparing adjusters."""

    NAME = "none"
    PARAMS: ClassVar[dict[str, float]] = {}

    def update(self, inp: AdjustInputs) -> Speeds:
        return self._with_horizontal(inp, inp.horizontal_mm_s)


class QueueProportional(Adjuster):
    """The thesis's first attempt: faster when the queue is short, slower when long.

    Kept as a baseline; the thesis found it satisfied by a long queue on a crawling belt.
    """

    NAME = "queue_proportional"
    PARAMS: ClassVar[dict[str, float]] = {
        "target": 10.0,
        "gain": 5.0,
        "min_mm_s": 50.0,
        "max_mm_s": 300.0,
        "nominal_mm_s": 150.0,
    }

    def _check(self) -> None:
        self._check_range()

    def update(self, inp: AdjustInputs) -> Speeds:
        p = self.params
        speed = p["nominal_mm_s"] + p["gain"] * (p["target"] - inp.queue_len)
        return self._with_horizontal(inp, self._clamp(speed))


class WaterMarks(Adjuster):
    """Thesis Figure 8-2: step down above ``high``, step up below ``low``, else pull.

    Between the marks the speed moves a fraction ``gain`` of the way to ``median_mm_s``.
    The result always lies in [``min_mm_s``, ``max_mm_s``], even if the current speed
    did not (an operator may have set it by hand).
    """

    NAME = "water_marks"
    PARAMS: ClassVar[dict[str, float]] = {
        "high": 100.0,
        "low": 50.0,
        "gain": 0.1,
        "step": 5.0,
        "min_mm_s": 50.0,
        "max_mm_s": 300.0,
        "median_mm_s": 150.0,
    }

    def _check(self) -> None:
        self._check_range()
        p = self.params
        if p["low"] > p["high"]:
            raise AdjusterParamError("low", "must not exceed high")
        if not 0.0 <= p["gain"] <= 1.0:
            raise AdjusterParamError("gain", "must be in [0, 1] or the pull overshoots")
        if p["step"] < 0:
            raise AdjusterParamError("step", "must not be negative")
        if not p["min_mm_s"] <= p["median_mm_s"] <= p["max_mm_s"]:
            raise AdjusterParamError("median_mm_s", "must lie within [min_mm_s, max_mm_s]")

    def update(self, inp: AdjustInputs) -> Speeds:
        p = self.params
        cur = inp.horizontal_mm_s
        if inp.queue_len > p["high"]:
            new = cur - p["step"]
        elif inp.queue_len < p["low"]:
            new = cur + p["step"]
        # Figure 8-2's two branches are the same formula; kept as written for reference.
        elif cur > p["median_mm_s"]:
            new = cur - p["gain"] * (cur - p["median_mm_s"])
        else:
            new = cur + p["gain"] * (p["median_mm_s"] - cur)
        return self._with_horizontal(inp, self._clamp(new))


class SupplyQueue(Adjuster):
    """Control the supply, not only the conveyor: the incline speed sets how many parts
    leave the hopper (about ``release_per_mm`` per mm of incline travel), so it is the
    incline — not the horizontal belt — that decides whether the robot has parts to choose
    from. Every period the incline % moves by ``gain_pct`` per part of error between the
    queue and ``target_queue`` (an integral controller), within [``min_incline_pct``,
    ``max_incline_pct``]; the horizontal speed is pulled a fraction ``pull`` of the way to
    ``horizontal_mm_s`` each period, which sets the density the supply lands at.

    Unlike the thesis's adjusters, a long queue on a crawling belt does not satisfy it:
    the belt speed is held, so a long queue means parts passing the robot, and the supply
    is cut back.
    """

    NAME = "supply_queue"
    PARAMS: ClassVar[dict[str, float]] = {
        "target_queue": 8.0,
        "gain_pct": 1.0,
        "min_incline_pct": 20.0,
        "max_incline_pct": 120.0,
        "horizontal_mm_s": 200.0,
        "pull": 0.2,
        "min_mm_s": 50.0,
        "max_mm_s": 300.0,
    }

    def _check(self) -> None:
        self._check_range()
        p = self.params
        if p["min_incline_pct"] > p["max_incline_pct"]:
            raise AdjusterParamError("min_incline_pct", "must not exceed max_incline_pct")
        if p["min_incline_pct"] < 0:
            raise AdjusterParamError("min_incline_pct", "must not be negative")
        if not 0.0 <= p["pull"] <= 1.0:
            raise AdjusterParamError("pull", "must be in [0, 1] or the pull overshoots")
        if not p["min_mm_s"] <= p["horizontal_mm_s"] <= p["max_mm_s"]:
            raise AdjusterParamError("horizontal_mm_s", "must lie within [min_mm_s, max_mm_s]")

    def envelope(self, incline_pct: float) -> list[Envelope]:
        """The incline runs at up to ``max_incline_pct`` % of a belt at up to ``max_mm_s``
        (an operator may set the belt anywhere in [min_mm_s, max_mm_s])."""
        p = self.params
        top, pct = p["max_mm_s"], p["max_incline_pct"]
        return [Envelope("max_mm_s", "horizontal", top, f"{top:g} mm/s"),
                Envelope("max_incline_pct", "incline", top * pct / 100.0,
                         f"{pct:g} % of max_mm_s {top:g} mm/s")]

    def update(self, inp: AdjustInputs) -> Speeds:
        p = self.params
        incline = inp.incline_pct + p["gain_pct"] * (p["target_queue"] - inp.queue_len)
        incline = min(max(incline, p["min_incline_pct"]), p["max_incline_pct"])
        h = inp.horizontal_mm_s + p["pull"] * (p["horizontal_mm_s"] - inp.horizontal_mm_s)
        return Speeds(self._clamp(h), incline, inp.robot_speed_pct)


def make_adjuster(name: str, params: Mapping[str, float] | None = None) -> Adjuster:
    """Build the adjuster a scenario names; a wrong name or key is a ValueError."""
    cls = ADJUSTERS.get(name)
    if cls is None:
        known = ", ".join(sorted(ADJUSTERS))
        raise ValueError(f"unknown adjust algorithm {name!r} (known: {known})")
    return cls(params or {})
