"""A supply plan carried out on the simulated world (``docs/supply.md``).

``apply_supply`` schedules the plan's events on the world's own queue (``World.schedule``),
so they happen at exact virtual times however the world is stepped: totes of new parts
tipped into the hopper, placed parts shipped out of the cell instead of recycled, the
incline's lift changing, the operator's speed override going down and back up.

Every part keeps its identity: a tote's parts are new parts with new ids (counted as
supplied), a shipped part goes to the world's ``shipped`` place; the world's accounting
checks every move as before, so ``parts.lost`` and ``parts.duplicated`` keep their
meaning. Tote contents are drawn from the plan's own generator (seeded from the plan's
seed and the run's), never from the world's stream.
"""

from __future__ import annotations

import dataclasses
import math
from collections import Counter
from collections.abc import Callable
from typing import Any

from feeder_bt.config.supply import SupplyPlanSpec, Totes
from feeder_bt.core.errors import FeederError
from feeder_bt.core.model import Scenario
from feeder_bt.sim.devices import SimHal
from feeder_bt.sim.faults import plan_rng
from feeder_bt.sim.world import World

RAMP_STEP_S = 5.0          # a friction ramp changes the lift in steps this long


def with_start(scenario: Scenario, plan: SupplyPlanSpec | None) -> Scenario:
    """The scenario with the plan's starting hopper (``start``) instead of its own."""
    if plan is None or plan.start is None:
        return scenario
    return dataclasses.replace(scenario, hopper={k: v for k, v in plan.start.items()})


def tote_counts(n: int, weights: dict[str, float]) -> dict[str, int]:
    """``n`` parts split by ``weights`` (largest remainders: the counts add up to ``n``
    and each is within one of its share)."""
    total = sum(weights.values())
    shares = {k: n * w / total for k, w in weights.items()}
    counts = {k: math.floor(s) for k, s in shares.items()}
    left = n - sum(counts.values())
    for k in sorted(shares, key=lambda k: -(shares[k] - counts[k]))[:left]:
        counts[k] += 1
    return counts


class SupplyDriver:
    """Carries out a supply plan on one simulated world; ``log`` says what it did."""

    def __init__(self, world: World, plan: SupplyPlanSpec, seed: int) -> None:
        self.world, self.plan = world, plan
        self.rng = plan_rng(plan.seed, seed, 5)
        self.log: list[dict[str, Any]] = []
        self.totes = 0
        self.initial = world.total
        self.arrivals: list[tuple[float, int]] = []     # (s into the run, parts): each tote
        # the same by part type (a kit's inflow bound, kits.py)
        self.initial_by_type = dict(Counter(p.type for p in world.parts.values()))
        self.arrivals_by_type: list[tuple[float, dict[str, int]]] = []
        self.t0 = world.now()
        world.ship_placed = plan.ship_placed
        if plan.totes is not None:
            t = plan.totes
            first = t.every_s if t.first_at_s is None else t.first_at_s
            self._at(first, self._tote)
        for fc in plan.friction:
            self._at(fc.at_s, lambda now, fc=fc: self._friction(now, fc.lift, fc.ramp_s))
        for op in plan.operator:
            self._at(op.at_s, lambda now, op=op: self._override(now, op.override_pct))
            if op.for_s is not None:
                self._at(op.at_s + op.for_s, lambda now: self._override(now, 100.0))

    def _at(self, after_s: float, fn: Callable[[float], None]) -> None:
        self.world.schedule(self.t0 + after_s, fn)

    def _note(self, t: float, kind: str, detail: str) -> None:
        self.log.append({"t": round(t - self.t0, 3), "kind": kind, "detail": detail})

    # ------------------------------------------------------------------ totes
    def mix(self, t: float) -> dict[str, float]:
        """The tote mix ``t`` seconds (world time) into the run: the plan's ``mix`` (or the
        scenario's hopper mix), drifting linearly to ``drift_to`` over ``drift_s``."""
        tot: Totes = self.plan.totes          # type: ignore[assignment]
        start = tot.mix or _hopper_mix(self.world.scenario)
        if not tot.drift_to:
            return _normal(start)
        f = min(1.0, max(0.0, (t - self.t0) / tot.drift_s))       # type: ignore[operator]
        a, b = _normal(start), _normal(tot.drift_to)
        return {k: (1 - f) * a.get(k, 0.0) + f * b.get(k, 0.0) for k in {**a, **b}}

    def _tote(self, t: float) -> None:
        tot: Totes = self.plan.totes          # type: ignore[assignment]
        counts = tote_counts(tot.parts, self.mix(t))
        order = [k for k, n in sorted(counts.items()) for _ in range(n)]
        self.rng.shuffle(order)
        self.world.add_parts(order)
        self.totes += 1
        self.arrivals.append((t - self.t0, len(order)))
        self.arrivals_by_type.append((t - self.t0, counts))
        what = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()) if n)
        self._note(t, "tote", f"tote {self.totes}: {what} into the hopper "
                              f"({len(self.world.hopper)} there now)")
        self._at(t - self.t0 + tot.every_s, self._tote)

    # ------------------------------------------------------------------ friction, operator
    def _friction(self, t: float, lift: float, ramp_s: float) -> None:
        start = self.world.lift
        if ramp_s <= 0:
            self._set_lift(lift)
            self._note(t, "friction", f"incline lifts {lift:.0%} of its nominal rate")
            return
        steps = max(1, math.ceil(ramp_s / RAMP_STEP_S))
        self._note(t, "friction", f"incline lift ramps from {start:.0%} to {lift:.0%} of its "
                                  f"nominal rate over {ramp_s:g} s")
        for k in range(1, steps + 1):
            value = start + (lift - start) * k / steps
            self.world.schedule(t + ramp_s * k / steps,
                                lambda now, v=value: self._set_lift(v))

    def _set_lift(self, lift: float) -> None:
        self.world.lift = lift
        self.world.redraw_release()

    def _override(self, t: float, pct: float) -> None:
        self.world.speed_override_pct = pct
        self._note(t, "operator", f"robot speed override {pct:g} %")

    # ------------------------------------------------------------------ report
    def inflow(self) -> tuple[int, list[tuple[float, int]]] | None:
        """(parts at the start, tote arrivals) when placed parts leave the cell, for the
        report's inflow bound (``feeder_bt.policy.supply_bound``); ``None`` when they go back to
        the hopper (then nothing bounds what enters)."""
        return (self.initial, list(self.arrivals)) if self.plan.ship_placed else None

    def inflow_by_type(self) -> dict[str, tuple[int, list[tuple[float, int]]]] | None:
        """``inflow`` for each part type."""
        if not self.plan.ship_placed:
            return None
        types = set(self.initial_by_type) | {t for _, c in self.arrivals_by_type for t in c}
        return {t: (self.initial_by_type.get(t, 0),
                    [(s, c[t]) for s, c in self.arrivals_by_type if c.get(t)])
                for t in types}

    def report(self) -> dict[str, Any]:
        w = self.world
        return {"plan": str(self.plan.path), "totes": self.totes, "initial": self.initial,
                "supplied": w.counts["supplied"], "shipped": w.counts["shipped"],
                "in_cell": len(w.parts) - len(w.shipped), "log": self.log[:200]}


def _hopper_mix(scenario: Scenario) -> dict[str, float]:
    mix = {k: float(v) for k, v in scenario.hopper.items() if v > 0}
    return mix or {k: 1.0 for k in scenario.parts}


def _normal(weights: dict[str, float]) -> dict[str, float]:
    total = sum(weights.values())
    return {k: w / total for k, w in weights.items()}


def apply_supply(hal: Any, plan: SupplyPlanSpec, seed: int | None = None) -> SupplyDriver:
    """Carry out ``plan`` on a simulated cell from now on; ``seed`` is the run's (default:
    the world's), mixed with ``plan.seed`` for the tote draws. Only the simulated cell
    takes a plan: real parts arrive however the plant brings them."""
    if not isinstance(hal, SimHal):
        raise FeederError(f"supply plans drive the simulated cell only (--hal sim), not a "
                          f"{getattr(hal, 'kind', type(hal).__name__)} cell")
    if "supply" in hal.extras:
        raise FeederError("this simulated cell already has a supply plan")
    driver = SupplyDriver(hal.world, plan, hal.world.seed if seed is None else seed)
    hal.extras["supply"] = driver
    return driver
