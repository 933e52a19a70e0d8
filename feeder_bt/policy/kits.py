"""Kits (thesis 8.2.1.5: "an assembly sequence might specify that first a washer be
retrieved and then a nut"): the parts of one kit, by type and count, placed in any order
(``retrieve.kit``) or in a fixed one (``retrieve.sequence``).

The kit advances when a part is *placed*, not when it is chosen: a missed pick leaves the
kit still wanting that part, so an assembly never goes without its washer.

A station may hold several kits at once (``retrieve.open_kits``: trays, fixtures): a part
goes to the fullest open kit that takes it, so a finished kit leaves as soon as it can, and
the robot need not wait for the one type that a single open kit lacks.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Sequence

from feeder_bt.core.model import RetrieveParams
from feeder_bt.policy.supply_bound import inflow_bound_parts


class KitTracker:
    """What the open kits still need, from the parts placed so far."""

    def __init__(self, counts: dict[str, int], order: Sequence[str] = (),
                 open_kits: int = 1) -> None:
        self.counts = dict(counts)
        self.order = list(order)
        self.size = sum(self.counts.values())
        self.open_kits = max(1, int(open_kits))
        self.kits: list[Counter[str]] = [Counter() for _ in range(self.open_kits)]
        self.completed = 0

    @classmethod
    def of(cls, retrieve: RetrieveParams) -> KitTracker | None:
        """The scenario's kit (a ``sequence`` is a kit in order); None without one."""
        if retrieve.sequence:
            return cls(Counter(retrieve.sequence), retrieve.sequence, retrieve.open_kits)
        if retrieve.kit:
            return cls(retrieve.kit, (), retrieve.open_kits)
        return None

    @property
    def have(self) -> Counter[str]:
        """The fullest open kit's parts (the one kit, with ``open_kits`` 1)."""
        return self.kits[self._fullest()[0]]

    def _fullest(self) -> list[int]:
        """The open kits, fullest first (the first opened first among equals)."""
        return sorted(range(len(self.kits)), key=lambda i: -sum(self.kits[i].values()))

    def _takes(self, kit: Counter[str], ptype: str) -> bool:
        if self.order:
            i = sum(kit.values())
            return i < self.size and self.order[i] == ptype
        return kit[ptype] < self.counts.get(ptype, 0)

    def _into(self, kits: list[Counter[str]], ptype: str) -> int | None:
        """The fullest of ``kits`` that takes ``ptype`` next (None: none does)."""
        for i in sorted(range(len(kits)), key=lambda i: -sum(kits[i].values())):
            if self._takes(kits[i], ptype):
                return i
        return None

    def wanted(self, in_flight: Counter[str] | None = None) -> set[str]:
        """The part types some open kit takes next: in order, each kit's next one; else any
        a kit lacks. ``in_flight``: parts handed out and not yet placed (robots of the part
        server), already promised to the kits; empty when all they lack are on their way."""
        kits = [Counter(k) for k in self.kits]
        going = Counter(in_flight or ())
        while going:                 # in a kit's order: a nut waits for its washer
            took = False
            for ptype in sorted(going):
                i = self._into(kits, ptype)
                if i is not None:
                    kits[i][ptype] += 1
                    going[ptype] -= 1
                    took = True
            going = +going
            if not took:
                break
        return {t for t in self.counts for k in kits if self._takes(k, t)}

    def placed(self, ptype: str) -> bool:
        """A part of ``ptype`` was placed; True when it completed a kit. A part no open kit
        wanted (one held from before a restart) is not counted into one."""
        i = self._into(self.kits, ptype)
        if i is None:
            return False
        self.kits[i][ptype] += 1
        if sum(self.kits[i].values()) < self.size:
            return False
        self.kits[i] = Counter()
        self.completed += 1
        return True


def kit_bounds(counts: dict[str, int], in_reach: dict[str, int], feed_seconds: float,
               robot_ppm: float, inflow: dict[str, tuple[int, list[tuple[float, int]]]] | None,
               span_s: float, lag_s: float = 0.0, selection_kits: int | None = None,
               open_kits: int = 1) -> dict[str, float]:
    """Kits per minute no feeder could beat: the robot's (``robot_ppm`` over the parts a
    kit holds), the supply's (each type's parts that came within reach, over the kit's
    count of it) and, when placed parts leave the cell, the inflow's.

    The inflow bound in kits: the kits done by the end are at most those whose parts of
    each type had reached the robot by some time ``s`` (``A_t(s) / n_t``; an arrival
    counts ``lag_s`` after it, the ride to the robot) plus what the robot builds after
    ``s``: a kit takes ``size`` cycles, so ``robot_ppm / size`` kits a minute, plus the
    kits a part of which was placed before ``s`` (one per open kit, ``open_kits``). ``selection_kits``: kits a
    nearest-first robot completes from the run's passes, taking only the types the kit
    wants (``robot_bounds.selection_bound``; simulated runs only), a yardstick as the
    parts' selection rate is: reported beside the bounds, never the ceiling."""
    if feed_seconds <= 0:
        return {}
    per_min = 60.0 / feed_seconds
    size = sum(counts.values())
    out = {"robot_bound_kpm": robot_ppm / size,
           "supply_bound_kpm": min(in_reach.get(t, 0) * per_min / n for t, n in counts.items())}
    if inflow is not None:
        out["inflow_bound_kpm"] = min(
            _kit_inflow(*inflow.get(t, (0, [])), n, robot_ppm / size, span_s, lag_s,
                        open_kits) * per_min
            for t, n in counts.items())
    out = {k: round(v, 3) for k, v in out.items()}
    out["ceiling_kpm"] = min(out.values())
    if selection_kits is not None:          # a yardstick: after the ceiling is taken
        out["selection_bound_kpm"] = round(selection_kits * per_min, 3)
    return out


def steady_kits(counts: dict[str, int], placed: int, feed_seconds: float,
                cycles_s: float) -> dict[str, float]:
    """The steady-state kit bound priced at the run's measured robot cycle: with
    ``cycles_s`` of feeding spent on pick-and-place cycles that placed ``placed`` parts
    (``robot_time``), the measured cycle is ``cycles_s / placed`` and the share of feeding
    on cycles ``cycles_s / feed_seconds``; at that cycle and share no pick order builds
    more than ``60 * share / cycle / size`` kits a minute (every placed part in a finished
    kit), which is the run's parts/min over the kit's size. A bound for that cycle and that
    share, not for the cell: a cheaper cycle or less waiting raises it."""
    size = sum(counts.values())
    if placed <= 0 or feed_seconds <= 0 or cycles_s <= 0 or size <= 0:
        return {}
    cycle = cycles_s / placed
    share = cycles_s / feed_seconds
    return {"robot_cycle_s": round(cycle, 4), "cycles_share": round(share, 4),
            "steady_at_cycle_kpm": round(60.0 * share / cycle / size, 3)}


def _kit_inflow(initial: int, arrivals: list[tuple[float, int]], n: int, kits_pm: float,
                span_s: float, lag_s: float, open_kits: int = 1) -> float:
    """Kits a type's arrivals allow (``n`` of it a kit) with a robot building ``kits_pm``:
    the parts' inflow bound (``supply_bound.inflow_bound_parts``) counted in kits."""
    return inflow_bound_parts(initial / n, [(t, k / n) for t, k in arrivals], kits_pm,
                              span_s, lag_s, begun=open_kits)


def kits_report(tracker: KitTracker, in_reach: dict[str, int], feed_seconds: float,
                robot_ppm: float, inflow: dict[str, tuple[int, list[tuple[float, int]]]] | None,
                span_s: float, lag_s: float = 0.0, selection_kits: int | None = None
                ) -> dict[str, object]:
    """The report's ``kits``: the kit, how many were completed and how fast, its bounds."""
    kpm = tracker.completed * 60.0 / feed_seconds if feed_seconds > 0 else 0.0
    bounds = kit_bounds(tracker.counts, in_reach, feed_seconds, robot_ppm, inflow, span_s,
                        lag_s, selection_kits, tracker.open_kits)
    ceil = bounds.get("ceiling_kpm", math.inf)
    return {"kit": tracker.counts, "order": tracker.order or "any",
            "open_kits": tracker.open_kits,
            "completed": tracker.completed, "per_minute": round(kpm, 3), **bounds,
            "of_ceiling_pct": round(100.0 * kpm / ceil, 1) if 0 < ceil < math.inf else None}


def describe_kits(k: dict) -> str:
    """A report's ``kits``: how many, how fast, against the kit ceiling (and which bound
    it is) and the steady-state bound at the measured cycle, as the run's summary and
    ``feeder report`` say it."""
    kit = " + ".join(f"{n} {t}" for t, n in k["kit"].items()) + (
        f", {k['open_kits']} open at once" if k.get("open_kits", 1) > 1 else "")
    which = next((name[:-len("_bound_kpm")] for name, v in k.items()
                  if name.endswith("_bound_kpm") and name != "selection_bound_kpm"
                  and name != "steady_at_cycle_kpm" and v == k.get("ceiling_kpm")), None)
    of = (f", {k['of_ceiling_pct']:.0f} % of the kit ceiling {k['ceiling_kpm']:.1f}"
          + (f" ({which} bound)" if which else "")
          if k.get("of_ceiling_pct") is not None else "")
    steady = k.get("steady_at_cycle_kpm")
    if steady:
        of += (f"; {100.0 * k['per_minute'] / steady:.0f} % of {steady:.2f} at the measured "
               f"{k['robot_cycle_s']:.2f} s cycle")
    return f"kits {k['completed']} ({kit}): {k['per_minute']:.1f} kits/min{of}"
