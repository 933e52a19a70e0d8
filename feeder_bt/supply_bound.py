"""The supply bound: how fast pickable, singulated parts reach the robot.

``robot_bound_ppm`` says how fast the robot could place parts if one were always waiting at
the best point of its window; the supply bound says how fast parts the robot *could* take
pass through its reachable window: parts the locator found pickable (a part touching
another is one blob that fits no class, so a located part is singulated) whose path along
the belt meets the reach before ``too_far``, per minute of feeding. No feeder setting can
place parts faster than either; the lower one is the run's ceiling (``feeder_bt.report``).

It is counted from what the controller sees (``Enqueue`` counts ``located_in_reach``), so
it is the same on a real cell; ``tests/test_supply.py`` checks it against the simulated
world's truth. A part that goes round again is supplied again: each pass is a chance.
"""

from __future__ import annotations

import math

from .scenario.model import CellSpec, Scenario


class ReachWindow:
    """The robot's reach along the belt: an annulus about its base, cut at ``too_far`` (or
    the belt's end). Parts travel along +x at constant y."""

    def __init__(self, cell: CellSpec, scenario: Scenario) -> None:
        r = cell.robot
        self.bx, self.by = r.base_mm
        self.outer, self.inner = r.reach_mm, r.inner_reach_mm
        self.x_hi = min(scenario.retrieve.too_far_mm, cell.conveyors["horizontal"].length_mm)
        self.offsets = {name: spec.tool_offset[:2] for name, spec in scenario.parts.items()}

    def spans(self, y: float) -> list[tuple[float, float]]:
        """The x intervals reachable at ``y`` (up to ``x_hi``)."""
        dy = abs(y - self.by)
        if dy > self.outer:
            return []
        w = math.sqrt(self.outer ** 2 - dy ** 2)
        lo, hi = self.bx - w, min(self.bx + w, self.x_hi)
        if dy >= self.inner:
            return [(lo, hi)] if lo <= hi else []
        iw = math.sqrt(self.inner ** 2 - dy ** 2)
        out = [(lo, min(self.bx - iw, hi)), (self.bx + iw, hi)]
        return [(a, b) for a, b in out if a <= b]

    def crosses(self, x: float, y: float, ptype: str | None = None) -> bool:
        """Whether a part at (x, y) on the belt passes a reachable point before ``x_hi``
        (the robot aims at the part plus its type's tool offset)."""
        ox, oy = self.offsets.get(ptype, (0.0, 0.0)) if ptype is not None else (0.0, 0.0)
        x, y = x + ox, y + oy
        return any(b >= x for _, b in self.spans(y))


def supply_bound_ppm(located_in_reach: int, feed_seconds: float) -> float:
    """Parts per minute that the robot could have taken, from the controller's count."""
    return located_in_reach * 60.0 / feed_seconds if feed_seconds > 0 else 0.0


def ceiling(robot_ppm: float, supply_ppm: float | None) -> tuple[str, float]:
    """(which bound, parts/min): the lower of the two is the ceiling (``None``: no supply
    bound known, the robot's then)."""
    if supply_ppm is None or robot_ppm <= supply_ppm:
        return "robot", robot_ppm
    return "supply", supply_ppm
