"""Fault plans: which faults the simulated cell injects, how often, and when.

A fault plan is a YAML file (``docs/faults.md``) read by ``files.load_fault_plan`` with the
scenario loader's machinery, so a mistake in it is one ``FILE:LINE: key: what`` line like a
mistake in a scenario. ``feeder_bt.sim.faults`` carries the plan out.

Each kind of fault has one natural rate unit: a servo time-out happens to a pick, a failed
grab to a frame, a dropped connection or a jam in the course of an hour. The plan accepts
only that unit for each kind, so ``grab_failed: {per_pick: ...}`` is an error rather than
a silently different fault rate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: Every fault kind a plan may name.
FAULT_KINDS: tuple[str, ...] = (
    "servo_timeout", "comms_lost", "grab_failed", "conveyor_jam", "missed_grab", "estop",
    "encoder_slip")

#: The one rate key each kind takes under ``rates`` (``estop`` is scripted only).
RATE_UNITS: dict[str, str] = {
    "servo_timeout": "per_pick",
    "comms_lost": "per_hour",
    "grab_failed": "per_frame",
    "conveyor_jam": "per_hour",
    "missed_grab": "per_pick",
    "encoder_slip": "per_hour",
}
RATE_KEYS: tuple[str, ...] = ("per_pick", "per_frame", "per_hour")

#: Which link a ``comms_lost`` drops; ``alternate`` takes galil, adept, galil, ... in turn.
COMMS_DEVICES: tuple[str, ...] = ("galil", "adept", "camera", "plate", "alternate")

#: The steps of a pick-and-place at which a scripted ``comms_lost`` may cut a link: the
#: first such step after ``at_s``. ``before_pick``: the pick command is never sent;
#: ``after_grip``: the robot gripped the part and its reply is lost; ``during_place``:
#: half-way through the move to the place pose; ``after_release``: the part is let go at
#: the place pose and the reply is lost. The robot finishes a motion it has started.
PHASES: tuple[str, ...] = ("before_pick", "after_grip", "during_place", "after_release")

#: The kind each injected kind is counted under in the report's ``faults`` and
#: ``recoveries``: the ``HalError.kind`` the trees see (``estop`` is the cell's own count).
ERROR_KINDS: dict[str, str] = {
    "servo_timeout": "servo_timeout",
    "comms_lost": "comms_lost",
    "grab_failed": "grab_failed",
    "conveyor_jam": "conveyor",
    "missed_grab": "missed_grab",
    "estop": "estop",
    "encoder_slip": "encoder_drift",
}


LINK_DEATHS = ("refused", "silent")   # comms_lost: how a link dies


@dataclass
class FaultRate:
    """How often one kind of fault happens; only the kind's unit (``RATE_UNITS``) is set."""

    per_pick: float | None = None        # probability per pick the robot starts
    per_frame: float | None = None       # probability per camera grab
    per_hour: float | None = None        # mean arrivals per hour of virtual time (Poisson)
    device: str = "alternate"            # comms_lost: galil | adept | camera | plate | alternate
    outage_s: float = 2.0                # comms_lost: how long the link stays down
    # comms_lost: how it dies. refused: every call fails at once (the controller gone, a
    # cable unplugged at a switch that resets the connection); silent: a pulled cable, no
    # FIN: each call waits out the driver's time-out before it fails, as on the drivers
    link: str = "refused"
    counts: int = 200                    # encoder_slip: counts the robot's counter gains

    def rate(self) -> tuple[str, float]:
        """(unit, value) of the one rate that is set (0 per hour if none)."""
        for key in RATE_KEYS:
            v = getattr(self, key)
            if v is not None:
                return key, v
        return "per_hour", 0.0


@dataclass
class ScriptedFault:
    """One fault at a given time (seconds after the run starts)."""

    at_s: float
    kind: str
    release_after_s: float = 30.0        # estop: how long the e-stop input stays pressed
    device: str = "alternate"            # comms_lost: as FaultRate.device
    outage_s: float = 2.0                # comms_lost: as FaultRate.outage_s
    link: str = "refused"                # comms_lost: as FaultRate.link
    phase: str | None = None             # comms_lost: at this step of the next pick (PHASES)
    counts: int = 200                    # encoder_slip: as FaultRate.counts


@dataclass
class FaultPlanSpec:
    """A whole fault plan: random rates by kind plus scripted faults."""

    seed: int = 0
    rates: dict[str, FaultRate] = field(default_factory=dict)
    scripted: list[ScriptedFault] = field(default_factory=list)
    path: Path = field(default_factory=Path)


# Keys that only mean something for some kinds: key -> the kinds that take it.
_ONLY_FOR: dict[str, tuple[str, ...]] = {
    "device": ("comms_lost",),
    "outage_s": ("comms_lost",),
    "link": ("comms_lost",),
    "phase": ("comms_lost",),
    "release_after_s": ("estop",),
    "counts": ("encoder_slip",),
}


def build_rates(ctx: Any, node: Any, path: str) -> dict[str, Any]:
    """``rates: {kind: {per_...: x, ...}}``: the kind is checked before its rate, so a
    misspelt kind is reported as such (with a did-you-mean), not as a bad rate."""
    out: dict[str, FaultRate] = {}
    entries = ctx.entries(node, path)
    g = ctx.gather(node)                  # every kind is checked, not only the first
    for kind, _, vnode in entries:
        with g.step(breaks=kind in RATE_UNITS):   # a wrong kind is left out, listed
            out[kind] = _build_rate(ctx, kind, vnode, f"{path}.{kind}", path)
    g.done()
    return {"rates": out}


def _build_rate(ctx: Any, kind: str, vnode: Any, sub: str, path: str) -> FaultRate:
    if kind == "estop":
        raise ctx.error(sub, "estop is scripted only: list it under `scripted` with "
                             "`at_s` and `release_after_s`",
                        line=ctx.key_lines.get(sub))
    if kind not in RATE_UNITS:
        ctx.unknown(kind, path, RATE_UNITS, what="fault kind")
    rate = ctx.dataclass(FaultRate, vnode, sub)
    unit = RATE_UNITS[kind]
    given = [k for k in RATE_KEYS if getattr(rate, k) is not None]
    for k in given:
        if k != unit:
            raise ctx.error(f"{sub}.{k}", f"{kind} takes {unit}, not {k}",
                            line=ctx.key_lines.get(f"{sub}.{k}"))
    if not given:   # a misspelt rate key ("did you mean") is that mistake, not a second one
        raise ctx.suggested.get(f"{sub}.{unit}") or ctx.error(
            sub, f"missing required key {unit!r} ({kind}'s rate)", line=ctx.key_lines.get(sub))
    _check_only_for(ctx, kind, sub)
    return rate


def check_fault_plan(plan: FaultPlanSpec, ctx: Any) -> None:
    """Checks across the fields of a scripted fault (which keys its kind takes)."""
    for i, sf in enumerate(plan.scripted):
        _check_only_for(ctx, sf.kind, f"scripted[{i}]")


def _check_only_for(ctx: Any, kind: str, path: str) -> None:
    for key, kinds in _ONLY_FOR.items():
        sub = f"{path}.{key}"
        if kind not in kinds and sub in ctx.key_lines:
            ctx.add_problem(sub, f"{key} applies only to {' and '.join(kinds)}, not {kind}",
                            line=ctx.key_lines[sub])


