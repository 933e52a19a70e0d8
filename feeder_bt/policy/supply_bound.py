"""The supply bound: how fast pickable, singulated parts reach the robot.

``robot_bound_ppm`` says how fast the robot could place parts if one were always waiting at
the best point of its window; the supply bound says how fast parts the robot *could* take
pass through its reachable window: parts the locator found pickable (a part touching
another is one blob that fits no class, so a located part is singulated) whose path along
the belt meets the reach before ``too_far``, per minute of feeding. No feeder setting can
place parts faster than either; the lower one is the run's ceiling (``feeder_bt.analysis.report``).

It is counted from what the controller sees (``Enqueue`` counts ``located_in_reach``), so
it is the same on a real cell; ``tests/config/test_supply.py`` checks it against the simulated
world's truth. A part that goes round again is supplied again: each pass is a chance.

When placed parts leave the cell and new ones come only in totes (a supply plan with
``ship_placed``), a third bound holds: the inflow bound. No feeder can place a part before
it has entered the cell, nor place faster than the robot bound, so by the end of feeding it
has placed at most ``min over s of A(s) + R (T - s)`` (plus one cycle cut by ``s``), with ``A(s)`` the parts that entered
by ``s`` and ``R`` the robot bound (the arrival curve met by the robot's service curve, as
in network calculus). The passes bound cannot see this: a part the hopper holds back goes
round and is counted at every pass.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from feeder_bt.core.model import CellSpec, Scenario


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


def inflow_bound_parts(initial: float, arrivals: Sequence[tuple[float, float]],
                       robot_ppm: float, span_s: float, lag_s: float = 0.0,
                       begun: float = 1.0) -> float:
    """The most parts any feeder could have placed in ``[0, span_s]`` when the cell held
    ``initial`` parts at 0 and ``arrivals`` (seconds, parts) came later, with a robot that
    places at most ``robot_ppm``: ``min over s of A(s) + R (span_s - s) + 1`` (the one
    for a cycle cut by ``s``). ``A`` is a staircase and ``R (span_s - s)`` falls, so the
    minimum is at 0, just before an arrival, or at the end (``A(span_s)``). A part that
    arrives at ``t`` reaches the robot no sooner than ``t + lag_s`` (``transport_lag_s``:
    the ride up the incline and along the belt), so each arrival counts from then; the
    cell starts with every part in the hopper (the simulated world does), so nothing is
    placed before ``lag_s``. ``begun``: the units under way at ``s`` (1 for parts: the one
    cycle; for kits, each kit open at once, ``kits._kit_inflow``)."""
    rate = robot_ppm / 60.0
    arrived = float(initial + sum(n for t, n in arrivals if t <= 0))
    best = arrived + rate * span_s + begun
    if lag_s > 0:
        best = min(best, rate * max(span_s - lag_s, 0.0) + begun)
    for t, n in sorted((t + lag_s, n) for t, n in arrivals if 0 < t):
        if t > span_s:
            break
        best = min(best, arrived + rate * (span_s - t) + begun)  # just before it came
        arrived += n
    return min(best, arrived)


def transport_lag_s(cell: CellSpec) -> float:
    """The shortest time from a tote's part entering the hopper to its reaching the robot:
    up the whole incline and along the horizontal belt from its start to the nearest point
    of the reach, both belts at their top speed (a lower bound on the real ride: the
    hopper's release, a landing downstream of the belt's start, slower belts all add)."""
    inc, hor = cell.conveyors["incline"], cell.conveyors["horizontal"]
    to_reach = max(cell.robot.base_mm[0] - cell.robot.reach_mm, 0.0)
    return inc.length_mm / inc.max_mm_s + to_reach / hor.max_mm_s


def ceiling(robot_ppm: float, supply_ppm: float | None,
            inflow_ppm: float | None = None) -> tuple[str, float]:
    """(which bound, parts/min): the lowest bound known is the ceiling (``None``: that
    bound not known; the robot's corner bound always is). Only bounds count: the mean
    cycle's and nearest-first selection's rates (``feeder_bt.analysis.robot_bounds``) move
    with each run's own setting and picks, so they are yardsticks, never the ceiling."""
    known = [("robot", robot_ppm), ("supply", supply_ppm), ("inflow", inflow_ppm)]
    return min(((k, v) for k, v in known if v is not None), key=lambda kv: kv[1])
