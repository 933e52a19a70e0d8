"""Supply plans: how parts reach the simulated cell, and how the cell's conditions drift.

A supply plan is a YAML file (``docs/supply.md``) beside the fault plans, read with the
scenario loader's machinery (``_Ctx``: node-walking, one ``FILE:LINE: key: what`` line per
mistake, unknown keys with a did-you-mean, ranges from the loader's tables). It describes
the conditions under which control matters and a fixed setting does not suffice: the hopper
refilled in totes with placed parts leaving the cell, a part mix that drifts, an incline
that lifts fewer parts as its friction changes, an operator who turns the robot down for a
while. ``feeder_bt.sim.supply`` carries a plan out on the simulated world.

Part types named by a plan are checked against the scenario it runs with
(``check_against_scenario``) before the cell opens, with the plan's own file and line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from feeder_bt.config import loader as L
from feeder_bt.core.errors import ConfigError


@dataclass
class Totes:
    """The hopper refilled in batches: a tote of ``parts`` parts every ``every_s``."""

    every_s: float
    parts: int
    first_at_s: float | None = None        # the first tote (default: after every_s)
    mix: dict[str, float] = field(default_factory=dict)   # weights by part type
    drift_to: dict[str, float] = field(default_factory=dict)   # the mix drifts to this
    drift_s: float | None = None           # ... linearly, reached this long after the start


@dataclass
class FrictionChange:
    """The incline's lift changes: ``lift`` times the cell's nominal release rate."""

    at_s: float
    lift: float
    ramp_s: float = 0.0                    # from the previous lift, linearly, over this long


@dataclass
class OperatorSlow:
    """The operator turns the robot's speed override down to ``override_pct`` for a while."""

    at_s: float
    override_pct: float
    for_s: float | None = None             # None: until the end of the run


@dataclass
class SupplyPlanSpec:
    """A whole supply plan: the hopper at the start, totes, shipping, friction, operator."""

    seed: int = 0
    start: dict[str, int] | None = None    # the hopper's content at the start
    ship_placed: bool = False              # placed parts leave the cell (shipped)
    totes: Totes | None = None
    friction: list[FrictionChange] = field(default_factory=list)
    operator: list[OperatorSlow] = field(default_factory=list)
    path: Path = field(default_factory=Path)
    lines: dict[str, int] = field(default_factory=dict)   # key -> line (loader-filled)


#: Sections and what each does, for messages and docs.
SECTIONS: dict[str, str] = {
    "start": "the hopper's content at the start, by part type",
    "ship_placed": "placed parts leave the cell instead of going back to the hopper",
    "totes": "the hopper refilled in batches",
    "friction": "the incline's lift rate changing over time",
    "operator": "the operator slowing the robot for a while",
}

L.RANGES.update({
    (Totes, "every_s"): L.POSITIVE,
    (Totes, "parts"): L.Range(lo=1),
    (Totes, "first_at_s"): L.NON_NEGATIVE,
    (Totes, "drift_s"): L.POSITIVE,
    (FrictionChange, "at_s"): L.NON_NEGATIVE,
    (FrictionChange, "lift"): L.Range(0, 2),
    (FrictionChange, "ramp_s"): L.NON_NEGATIVE,
    (OperatorSlow, "at_s"): L.NON_NEGATIVE,
    (OperatorSlow, "override_pct"): L.Range(0, 100, lo_open=True),
    (OperatorSlow, "for_s"): L.POSITIVE,
})
L._IMPLIED_FIELDS[SupplyPlanSpec] = frozenset({"lines"})


def load_supply_plan(path: str | Path) -> SupplyPlanSpec:
    """Load and validate a supply plan; every mistake is one ``ConfigError`` line."""
    path = Path(path)
    ctx = L._Ctx(str(path))
    root = L._compose(path, ctx)
    L._check_kind(root, "supply", path)
    plan = ctx.collect(ctx.dataclass, SupplyPlanSpec, root, "", fill={"path": path})
    if plan is not None:
        plan.lines = dict(ctx.key_lines)
        ctx.collect(_check, plan, ctx)
    ctx.raise_problems()
    return plan


def _check(plan: SupplyPlanSpec, ctx: Any) -> None:
    """What one key's range cannot say: weights, counts, pairs of keys, order in time."""
    for ptype, n in (plan.start or {}).items():
        if n < 0:
            raise ctx.error(f"start.{ptype}", f"must be >= 0, got {n}")
    t = plan.totes
    if t is not None:
        for key in ("mix", "drift_to"):
            weights = getattr(t, key)
            for ptype, w in weights.items():
                if w < 0:
                    raise ctx.error(f"totes.{key}.{ptype}", f"must be >= 0, got {L._num(w)}")
            if weights and sum(weights.values()) <= 0:
                raise ctx.error(f"totes.{key}", "needs a weight > 0 for some part type")
        if bool(t.drift_to) != (t.drift_s is not None):
            given, other = ("drift_to", "drift_s") if t.drift_to else ("drift_s", "drift_to")
            raise ctx.error(f"totes.{given}", f"{given} needs {other} (the mix drifts to "
                                              "drift_to over drift_s seconds)")
    last = -1.0
    for i, fc in enumerate(plan.friction):
        if fc.at_s < last:
            raise ctx.error(f"friction[{i}].at_s", f"changes must be in time order: "
                            f"{L._num(fc.at_s)} s comes before {L._num(last)} s")
        last = fc.at_s + fc.ramp_s
    for i, op in enumerate(plan.operator):
        for j, other in enumerate(plan.operator[:i]):
            end = other.at_s + other.for_s if other.for_s is not None else float("inf")
            if other.at_s <= op.at_s < end:
                raise ctx.error(f"operator[{i}].at_s", f"overlaps operator[{j}] "
                                f"({L._num(other.at_s)} s to {L._num(end)} s)")


def check_against_scenario(plan: SupplyPlanSpec, part_types: list[str]) -> None:
    """Every part type the plan names is one of the scenario's (with a did-you-mean); the
    plan's file and line, since the scenario is only known when the two meet."""
    named: list[tuple[str, str]] = [(f"start.{p}", p) for p in plan.start or {}]
    if plan.totes is not None:
        named += [(f"totes.{k}.{p}", p) for k in ("mix", "drift_to")
                  for p in getattr(plan.totes, k)]
    for key, ptype in named:
        if ptype not in part_types:
            hint = L._suggest(ptype, part_types) or f" (the scenario's: {', '.join(part_types)})"
            raise ConfigError(f"unknown part type {ptype!r}{hint}", file=str(plan.path),
                              line=plan.lines.get(key), key=key)
