"""The search space of ``feeder tune``: every trial is a legal scenario overlay.

Bounds come from the cell's axis limits (each conveyor's ``max_mm_s``) and the camera
window, so no trial asks an axis for more than it can do: incline speeds are sampled in
mm/s up to the incline's limit and turned into the percentages the scenario takes, divided
by the highest horizontal speed they go with. Three spaces, each with the same budget, and
each with the frame spacing and the pick policy free (a baseline gets every option ours
gets but belt control):

* ``ours``: adjuster (none, water_marks, supply_queue) and its parameters, belt and
  incline speeds;
* ``watermarks``: the thesis's water-mark adjuster's parameters (the baseline tuned for
  this cell);
* ``fixed``: one constant belt and incline speed, no adjuster; ``grid_space`` gives it as a
  grid over the two speeds and the policies, for a search that must not miss a corner of a
  small space.

A new study's first trial is the scenario as written, where it is a point of the space
(``start_params``): the search starts from what the cell runs now, so the best it
reports is never worse than that on the tuning seeds.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from feeder_bt.config.loader import RANGES, RETRIEVE_POLICIES, part_size_mm
from feeder_bt.core.model import CellSpec, PresentParams, Scenario
from feeder_bt.policy.adjusters import make_adjuster

SPACES = ("ours", "watermarks", "fixed")
ADJUSTERS = ("none", "water_marks", "supply_queue")
MIN_BELT_MM_S = 50.0          # slower belts starve the robot on every shipped part
MIN_INCLINE_MM_S = 10.0
#: the highest incline % a scenario may give (the loader's range of present.incline_pct)
MAX_INCLINE_PCT = float(RANGES[(PresentParams, "incline_pct")].hi or 200.0)


@dataclass(frozen=True)
class Limits:
    """What bounds the search: the axes' top speeds and the largest legal frame spacing."""

    horizontal_mm_s: float
    incline_mm_s: float
    frame_spacing_mm: float      # exclusive: the camera window minus the largest part

    @classmethod
    def of(cls, scenario: Scenario, cell: CellSpec) -> Limits:
        window = cell.camera.height_px * cell.camera.calibration.mm_per_px
        size = max(part_size_mm(p) for p in scenario.parts.values())
        return cls(cell.conveyors["horizontal"].max_mm_s, cell.conveyors["incline"].max_mm_s,
                   window - size)


def _r(x: float, digits: int = 2) -> float:
    """Rounded, so the overlay reads well and a rerun of it is the trial itself."""
    return round(float(x), digits)


def _pct(incline_mm_s: float, horizontal_mm_s: float) -> float:
    """The incline % that gives at most ``incline_mm_s`` at ``horizontal_mm_s``."""
    pct = min(_r(100.0 * incline_mm_s / horizontal_mm_s, 2), MAX_INCLINE_PCT)
    while pct * horizontal_mm_s / 100.0 > incline_mm_s:      # rounding must not go over
        pct = _r(pct - 0.01, 2)
    return pct


def _fixed(trial: Any, lim: Limits, prefix: str) -> dict[str, Any]:
    h = _r(trial.suggest_float(f"{prefix}belt_mm_s", MIN_BELT_MM_S, lim.horizontal_mm_s))
    inc = trial.suggest_float(f"{prefix}incline_mm_s", MIN_INCLINE_MM_S, lim.incline_mm_s)
    return {"present": {"horizontal_mm_s": h, "incline_pct": _pct(inc, h)},
            "adjust": {"algorithm": "none"}}


def _water_marks(trial: Any, lim: Limits, prefix: str) -> dict[str, Any]:
    low = _r(trial.suggest_float(f"{prefix}low", 0.0, 60.0))
    high = _r(low + trial.suggest_float(f"{prefix}band", 1.0, 80.0))
    lo = _r(trial.suggest_float(f"{prefix}min_mm_s", MIN_BELT_MM_S, lim.horizontal_mm_s))
    hi = _r(lo + trial.suggest_float(f"{prefix}max_over_min", 0.0, 1.0)
            * (lim.horizontal_mm_s - lo))
    med = _r(lo + trial.suggest_float(f"{prefix}median_at", 0.0, 1.0) * (hi - lo))
    med = min(max(med, lo), hi)
    inc = trial.suggest_float(f"{prefix}incline_at_max_mm_s", MIN_INCLINE_MM_S,
                              lim.incline_mm_s)
    params = {"high": high, "low": low,
              "gain": _r(trial.suggest_float(f"{prefix}gain", 0.01, 1.0), 3),
              "step": _r(trial.suggest_float(f"{prefix}step", 1.0, 30.0)),
              "min_mm_s": lo, "max_mm_s": hi, "median_mm_s": med}
    return {"present": {"horizontal_mm_s": med, "incline_pct": _pct(inc, max(hi, med))},
            "adjust": {"algorithm": "water_marks", "params": params}}


def _supply_queue(trial: Any, lim: Limits, prefix: str) -> dict[str, Any]:
    h = _r(trial.suggest_float(f"{prefix}belt_mm_s", MIN_BELT_MM_S, lim.horizontal_mm_s))
    inc = trial.suggest_float(f"{prefix}max_incline_mm_s", MIN_INCLINE_MM_S, lim.incline_mm_s)
    top = _pct(inc, h)
    params = {"target_queue": _r(trial.suggest_float(f"{prefix}target_queue", 2.0, 60.0)),
              "gain_pct": _r(trial.suggest_float(f"{prefix}gain_pct", 0.1, 10.0, log=True), 3),
              "min_incline_pct": min(_r(0.2 * top), 20.0), "max_incline_pct": top,
              "horizontal_mm_s": h, "min_mm_s": min(MIN_BELT_MM_S, h), "max_mm_s": h}
    return {"present": {"horizontal_mm_s": h, "incline_pct": _r(top / 2)},
            "adjust": {"algorithm": "supply_queue", "params": params}}


def _spacing_range(lim: Limits) -> tuple[float, float]:
    return 0.4 * lim.frame_spacing_mm, 0.95 * lim.frame_spacing_mm


def suggest(trial: Any, space: str, lim: Limits) -> dict[str, Any]:
    """Ask ``trial`` (an Optuna trial) for one point of ``space``; the overlay it means."""
    if space == "fixed":
        overlay = _fixed(trial, lim, "")
    elif space == "watermarks":
        overlay = _water_marks(trial, lim, "")
    elif space == "ours":
        algorithm = trial.suggest_categorical("adjuster", list(ADJUSTERS))
        build = {"none": _fixed, "water_marks": _water_marks, "supply_queue": _supply_queue}
        overlay = build[algorithm](trial, lim, f"{algorithm}.")
    else:
        raise ValueError(f"unknown search space {space!r} (known: {', '.join(SPACES)})")
    overlay["locate"] = {"frame_spacing_mm": _r(trial.suggest_float(
        "frame_spacing_mm", *_spacing_range(lim)))}
    overlay["retrieve"] = {"policy": trial.suggest_categorical("policy",
                                                               list(RETRIEVE_POLICIES))}
    return overlay


#: the smallest grid: two belt speeds by two incline speeds by every policy
GRID_MIN_TRIALS = 4 * len(RETRIEVE_POLICIES)


def grid_space(scenario: Scenario, lim: Limits, trials: int) -> dict[str, list[Any]]:
    """The ``fixed`` space as a grid within ``trials`` points: ``k`` belt speeds by ``k``
    incline speeds by every policy, at the scenario's frame spacing (held inside the
    searched range). A two-speed space is small: a grid cannot miss its corners, where
    TPE with a small budget may."""
    policies = list(RETRIEVE_POLICIES)
    k = max(2, int((trials / len(policies)) ** 0.5))
    lo, hi = _spacing_range(lim)

    def levels(a: float, b: float) -> list[float]:
        return [a + (b - a) * i / (k - 1) for i in range(k)]

    return {"belt_mm_s": levels(MIN_BELT_MM_S, lim.horizontal_mm_s),
            "incline_mm_s": levels(MIN_INCLINE_MM_S, lim.incline_mm_s),
            "frame_spacing_mm": [min(max(scenario.locate.frame_spacing_mm, lo), hi)],
            "policy": policies}


class _Check:
    """A stand-in trial that answers with given parameters and notes the ones outside
    their range, so that ``start_params`` is checked against the same bounds as a search."""

    def __init__(self, params: dict[str, Any]) -> None:
        self.params, self.bad = params, []

    def suggest_float(self, name: str, lo: float, hi: float, log: bool = False) -> float:
        v = self.params[name]
        if not lo - 1e-9 <= v <= hi + 1e-9:
            self.bad.append(name)
        return v

    def suggest_categorical(self, name: str, choices: list[Any]) -> Any:
        v = self.params[name]
        if v not in choices:
            self.bad.append(name)
        return v


def _scenario_params(scenario: Scenario, space: str, lim: Limits) -> dict[str, Any] | None:
    pr, adj = scenario.present, scenario.adjust
    algorithm = adj.algorithm if adj.leaf is None else "leaf"
    if space == "fixed" or (space == "ours" and algorithm == "none"):
        prefix = "none." if space == "ours" else ""
        out = {f"{prefix}belt_mm_s": pr.horizontal_mm_s,
               f"{prefix}incline_mm_s": pr.incline_pct * pr.horizontal_mm_s / 100.0}
    elif algorithm == "water_marks" and space in ("ours", "watermarks"):
        prefix = "water_marks." if space == "ours" else ""
        p = make_adjuster(algorithm, adj.params).params
        lo, hi, med = p["min_mm_s"], p["max_mm_s"], p["median_mm_s"]
        out = {f"{prefix}low": p["low"], f"{prefix}band": p["high"] - p["low"],
               f"{prefix}min_mm_s": lo,
               f"{prefix}max_over_min": (hi - lo) / (lim.horizontal_mm_s - lo)
               if lim.horizontal_mm_s > lo else 0.0,
               f"{prefix}median_at": (med - lo) / (hi - lo) if hi > lo else 0.0,
               f"{prefix}incline_at_max_mm_s": pr.incline_pct * max(hi, med) / 100.0,
               f"{prefix}gain": p["gain"], f"{prefix}step": p["step"]}
    elif algorithm == "supply_queue" and space == "ours":
        p = make_adjuster(algorithm, adj.params).params
        h = p["horizontal_mm_s"]
        out = {"supply_queue.belt_mm_s": h,
               "supply_queue.max_incline_mm_s": p["max_incline_pct"] * h / 100.0,
               "supply_queue.target_queue": p["target_queue"],
               "supply_queue.gain_pct": p["gain_pct"]}
    else:
        return None
    if space == "ours":
        out["adjuster"] = algorithm
    out.update(frame_spacing_mm=scenario.locate.frame_spacing_mm,
               policy=scenario.retrieve.policy)
    return out


def start_params(scenario: Scenario, space: str, lim: Limits) -> dict[str, Any] | None:
    """The scenario's own settings as parameters of ``space``, for a study's first trial;
    None where they are not a point of it (another adjuster, a value out of its bounds)."""
    params = _scenario_params(scenario, space, lim)
    if params is None:
        return None
    check = _Check({k: (round(v, 6) if isinstance(v, float) else v)
                    for k, v in params.items()})
    try:
        suggest(check, space, lim)
    except KeyError:
        return None
    return None if check.bad else check.params
