"""Pick policies: which located part the robot takes next (``retrieve.policy``).

Every policy prices reach with the robot model fitted online from the robot's measured
move times (``feeder_bt.robot.fit``; thesis Figure 8-5, "does location matter"): the
seconds from now until the part is released at its place pose, with the intercept on the
moving belt predicted from the belt speed, and infinite for a part no pick can catch any
more. ``fifo`` and ``earliest_deadline`` keep their order and take the first part of it
that can still be caught; ``shortest_cycle`` takes the cheapest, ``lookahead`` the
cheapest pair. The scenario's ``retrieve.reach_time_s`` is only a prior: the lead before
the fit has measured a move, and when there is no model. All parts of a choice are priced
at once with numpy, so a choice over a long queue stays well inside a tick.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from feeder_bt.behaviours.base import Ctx
from feeder_bt.core.model import belt_window
from feeder_bt.core.parts import Part
from feeder_bt.robot.fit import pricing_model, robot_fit

XNow = Callable[[Part], float]


def gone_by(ctx: Ctx, x_now: XNow, lead_mm: float) -> Callable[[Part], bool]:
    """Which queued parts no pick can have any more: past ``too_far`` by the time a pick
    would grip them (``lead_mm`` of belt on), or, tracking, already past the controller's
    pick limit (``core.model.belt_window``), where it refuses to start the pick."""
    r = ctx.scenario.retrieve
    pick_limit = belt_window(ctx.cell)[2] if r.tracking else math.inf
    parts = ctx.scenario.parts

    def gone(p: Part) -> bool:
        x = x_now(p)
        return x + lead_mm > r.too_far_mm or x + parts[p.type].tool_offset[0] > pick_limit
    return gone


@dataclass
class _Batch:
    """The candidate parts as columns: where each is now, and where each is placed."""

    x: np.ndarray          # belt x of the tool point (part + tool offset), now
    y: np.ndarray
    ox: np.ndarray         # tool offset along the belt (too_far is about the part itself)
    place_x: np.ndarray
    place_y: np.ndarray


class Policy:
    """How the next part is chosen; ``x_now`` predicts a part's belt x from the encoder.

    Every policy prices picks with the same model (``pricing_model``: fitted online from
    measured move times, or the cell's nominal model with ``retrieve.learn_robot:
    false``). A policy reads the robot's pose through ``ctx``; ``NextPart`` keeps
    ``belt_mm_s`` and ``robot_pct`` (the horizontal belt and robot speeds on the
    blackboard, which the adjuster or the operator may change) current before each choice.
    The base class is FIFO: the first part in the queue that can still be caught."""

    name = "fifo"

    def __init__(self, ctx: Ctx | None = None) -> None:
        self.ctx = ctx
        self.belt_mm_s = 0.0
        self.robot_pct = ctx.scenario.retrieve.robot_speed_pct if ctx is not None else 100.0
        # fitted online from measured move times (feeder_bt/robot/fit.py), not the
        # simulator's model; the cell's nominal model with retrieve.learn_robot: false
        self.model = pricing_model(ctx) if ctx is not None else None
        self.fit = robot_fit(ctx) if ctx is not None else None

    def has_data(self) -> bool:
        """Whether the model has anything to price with: a fit that has measured a move,
        or the cell's nominal model when the scenario does not learn."""
        if self.model is None or self.fit is None:
            return False
        return not self.fit.learning or sum(self.fit.samples.values()) > 0

    def lead_s(self) -> float:
        """How long before the grip a part must be dropped as too far. The pricing skips
        what cannot be caught, so only what no pick can reach in time is dropped: the
        settle and grip after the shortest possible move, by the model. Before the model
        has measured a move (or with no model) the scenario's ``reach_time_s`` is the
        prior."""
        if self.ctx is None:
            return 0.0
        if not self.has_data():
            return self.ctx.scenario.retrieve.reach_time_s
        assert self.model is not None
        sp, r = self.ctx.cell.robot, self.ctx.scenario.retrieve
        fastest = float(self.model.arch_times(np.zeros(1), self.robot_pct)[0])
        return fastest + (sp.track_settle_s if r.tracking else 0.0) + sp.grip_s

    def _batch(self, parts: list[Part], x_now: XNow) -> _Batch:
        assert self.ctx is not None
        specs = self.ctx.scenario.parts
        rows = []
        for p in parts:
            spec = specs[p.type]
            ox, oy, _ = spec.tool_offset
            rows.append((x_now(p) + ox, p.y_mm + oy, ox, spec.place.x, spec.place.y))
        cols = np.array(rows, dtype=float).reshape(-1, 5).T
        return _Batch(*cols)

    def costs(self, b: _Batch, start: tuple[float, float], speed_mm_s: float,
              after_s: float = 0.0) -> np.ndarray:
        """Seconds from a robot free at ``start`` ``after_s`` from now to each part's
        release (inf: not feasible), the parts having moved on meanwhile."""
        assert self.ctx is not None and self.model is not None
        r, sp = self.ctx.scenario.retrieve, self.ctx.cell.robot
        pct = self.robot_pct
        v = speed_mm_s if r.tracking else 0.0
        x0 = b.x + v * after_s
        sx, sy = start
        t = np.zeros_like(x0)
        for _ in range(4):                     # intercept on the moving belt
            t = self.model.arch_times(np.hypot(x0 + v * t - sx, b.y - sy), pct)
        up, _down, pick_limit = belt_window(self.ctx.cell)
        inside = self.model.reachable_mask(x0 + v * t, b.y)
        if v > 0:                              # the controller tracks only inside its window
            inside &= x0 + v * t >= up
        if not inside.all():                   # wait for parts still upstream of the reach
            bx, by = sp.base_mm
            half = np.sqrt(np.maximum(sp.reach_mm ** 2 - (b.y - by) ** 2, 0.0))
            x_enter = np.maximum(bx - half, up) + 1.0
            can_wait = (v > 0) & (np.abs(b.y - by) < sp.reach_mm) & (x0 + v * t <= x_enter)
            wait = (x_enter - x0) / v if v > 0 else np.zeros_like(x0)
            t = np.where(inside, t, np.where(can_wait, wait, np.inf))
        t_grip = t + (sp.track_settle_s if r.tracking else 0.0) + sp.grip_s
        x_grip = x0 + v * t_grip
        ok = np.isfinite(t_grip) & (x_grip - b.ox <= r.too_far_mm) & ((v == 0) | (x0 <= pick_limit)) \
            & self.model.reachable_mask(np.where(np.isfinite(x_grip), x_grip, 0.0), b.y)
        back = self.model.arch_times(np.hypot(x_grip - b.place_x, b.y - b.place_y), pct)
        return np.where(ok, t_grip + back + sp.release_s, np.inf)

    def cost(self, part: Part, x_now: XNow, speed_mm_s: float) -> float:
        """One part's seconds from now to its release at its place pose (inf: not feasible)."""
        assert self.ctx is not None
        pose = self.ctx.hal.robot_position.pose()
        return float(self.costs(self._batch([part], x_now), (pose.x, pose.y), speed_mm_s)[0])

    def priced(self, parts: list[Part], x_now: XNow) -> np.ndarray:
        """Every part's cost from the robot's pose now, at the current belt speed."""
        assert self.ctx is not None
        pose = self.ctx.hal.robot_position.pose()
        return self.costs(self._batch(parts, x_now), (pose.x, pose.y), self.belt_mm_s)

    def order(self, parts: list[Part], x_now: XNow) -> list[int]:
        """The policy's order over ``parts`` (indices): the queue's own for FIFO."""
        return list(range(len(parts)))

    def choose(self, parts: list[Part], x_now: XNow) -> Part | None:
        """The first part in the policy's order that can still be caught, by the same
        priced check ``shortest_cycle`` makes; if none can, the first in the order (the
        pick is tried, and a part that has gone is dropped at the next choice)."""
        if not parts:
            return None
        order = self.order(parts, x_now)
        if self.ctx is None or self.model is None:
            return parts[order[0]]
        c = self.priced(parts, x_now)
        for i in order:
            if math.isfinite(c[i]):
                return parts[i]
        return parts[order[0]]


class Fifo(Policy):
    name = "fifo"


class EarliestDeadline(Policy):
    """The part that leaves the pick window first (the one furthest down the belt) of
    those that can still be caught."""

    name = "earliest_deadline"

    def order(self, parts: list[Part], x_now: XNow) -> list[int]:
        xs = [x_now(p) for p in parts]
        return sorted(range(len(parts)), key=lambda i: -xs[i])


class ShortestCycle(Policy):
    """The part whose pick-and-place from the robot's current pose takes least time.

    A part still upstream of the reach costs its wait, and a part that would pass
    ``too_far`` before the grip is skipped. When parts arrive faster than the robot can
    take them, taking the cheap ones first turns the surplus into shorter cycles instead
    of longer queues."""

    name = "shortest_cycle"

    def choose(self, parts: list[Part], x_now: XNow) -> Part | None:
        if not parts:
            return None
        if self.ctx is None:
            return parts[0]
        c = self.priced(parts, x_now)
        i = int(np.argmin(c))
        return parts[i] if math.isfinite(c[i]) else max(parts, key=x_now)


class Lookahead(ShortestCycle):
    """Plans two picks, commits to the first: the part ``i`` that minimises the time to
    release ``i`` and then the best next part from ``i``'s place pose, the belt having
    moved on meanwhile.

    Shortest-cycle is greedy: it takes a cheap part now even when that part would be
    cheaper still a cycle later, further down the belt and nearer the place pose, and lets
    a part go that can only be had now. Pricing the pair takes the one about to leave and
    leaves the one still coming; only the ``CANDIDATES`` cheapest first picks are tried.
    """

    name = "lookahead"
    CANDIDATES = 6

    def choose(self, parts: list[Part], x_now: XNow) -> Part | None:
        if len(parts) < 2 or self.ctx is None:
            return super().choose(parts, x_now)
        pose = self.ctx.hal.robot_position.pose()
        b = self._batch(parts, x_now)
        first = self.costs(b, (pose.x, pose.y), self.belt_mm_s)
        order = [int(i) for i in np.argsort(first)[:self.CANDIDATES] if np.isfinite(first[i])]
        if not order:
            return max(parts, key=x_now)
        fallback = float(first[order[-1]])     # no second part in reach: a plain cycle
        best, best_i = math.inf, order[0]
        for i in order:
            then = self.costs(b, (b.place_x[i], b.place_y[i]), self.belt_mm_s,
                              after_s=float(first[i]))
            then[i] = np.inf
            nxt = float(then.min())
            total = float(first[i]) + (nxt if math.isfinite(nxt) else fallback)
            if total < best:
                best, best_i = total, i
        return parts[best_i]


POLICIES: dict[str, type[Policy]] = {
    "fifo": Fifo, "earliest_deadline": EarliestDeadline,
    "shortest_cycle": ShortestCycle, "lookahead": Lookahead}
