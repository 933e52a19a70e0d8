"""A plate cell's twin (``feeder twin fit`` on a ``presentation: plate`` cell).

What a plate cell's log holds that a real one records as well: every frame with its
finds (how many classed, how many pickable, the blobs' mean place along the feed) and its
rejected blobs; every plate action with its repetitions and its time from the command to
the feeder's done (``plate_done``); the timed picks and places.

- **directly from the log**: the action time. Each action takes ``reps * rep_s +
  settle_s`` (a flip forward one repetition more, ``sim/plate.py``); a least-squares line
  through the logged times against the repetitions gives both, with their errors.
- **by simulated moments** (``twin.fit_moments``): the dispense count from the parts
  picked per dispense repetition (what a dispense drops is picked, unless a crowded plate
  is purged: the count moves as the figure to about the power 0.4, measured between
  rounds; the blobs' area a dispense adds moves less, as dropped parts land on others);
  the flip's scatter from the frames after flips (the new pickable parts a
  flip, over the share of the blobs rejected as touching); the feed distance from how
  far the blobs' mean place moved along the feed per feed repetition. The flip's re-draw probability is not fitted
  (``PLATE_NOT_FITTED`` says why): the twin keeps the cell file's.
- the arm as on a belt cell (``twin.fit_arm``: static picks and places are timed moves).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from feeder_bt.core.model import CellSpec
from feeder_bt.tuning.twin import (
    MIN_COUNT,
    Estimate,
    Moment,
    RunLog,
    Twin,
    _flat,
    fit_arm,
    fit_moments,
    moves,
    untested,
)

#: the plate's figures no plate log fixes, and why
PLATE_NOT_FITTED = {
    "plate.bulk_nominal": "the bulk container's fill is not recorded, and the logged runs "
                          "kept it above the figure (placed parts return to it)",
    "plate.dispense_band_mm": "where a dispense lands is seen only as blobs the feed then "
                              "moves; its effect is within the dispense count's",
    "plate.purge_mm_per_rep": "the smart policy purged too seldom in the log to time it",
    "plate.feed_jitter_mm": "sideways wander is within the flip's scatter in every frame",
    "plate.feed_turn_deg": "a lens is round: a turn is invisible",
    "plate.feed_cv": "one feed's spread is within the feed distance's scatter",
    "plate.init_s": "homing happens once a run",
    "plate.flip_prob": "a flip's re-draw changes a lens's class seldom (85 % land flat "
                       "either way) and most flips part touching lenses: the unpickable "
                       "parts classed after flips against before them did not fix it in "
                       "the round trip (docs/plate-feeders.md)",
}

def _before(frames: list[tuple[float, dict]], t: float) -> dict | None:
    """The last frame at or before ``t``."""
    out = None
    for tf, f in frames:
        if tf > t + 1e-9:
            break
        out = f
    return out


def _after(frames: list[tuple[float, dict]], t: float) -> dict | None:
    """The first frame at or after ``t``."""
    for tf, f in frames:
        if tf >= t - 1e-9:
            return f
    return None


def plate_counts(run: RunLog) -> dict[str, float]:
    """The counts a plate fit matches (each from the log alone)."""
    c = {"held": 0.0, "dispense_reps": 0.0, "flips": 0.0, "after_blobs": 0.0,
         "after_rejected": 0.0, "after_new": 0.0, "unpick_before": 0.0, "unpick_after": 0.0, "feeds": 0.0,
         "feed_reps": 0.0, "feed_shift": 0.0}
    c["held"] = float(sum(1 for _, p in run.picks if p["outcome"] == "held"))
    for t, a in run.plate:
        action, reps = a["action"], int(a["reps"])
        t0 = t - float(a["dt"])
        before, after = _before(run.frames, t0), _after(run.frames, t)
        if action == "dispense":
            c["dispense_reps"] += reps
        if before is None or after is None:
            continue
        if action in ("flip", "flip_forward"):
            c["flips"] += 1
            c["after_blobs"] += after["parts"] + len(after["rejected"])
            c["after_rejected"] += len(after["rejected"])
            c["after_new"] += after["new"]
            c["unpick_before"] += before["parts"] - before.get("pickable", before["new"])
            c["unpick_after"] += after["parts"] - after.get("pickable", after["new"])
        elif action in ("feed_forward", "feed_backward") and \
                before.get("x_mm") is not None and after.get("x_mm") is not None:
            sign = 1.0 if action == "feed_forward" else -1.0
            c["feeds"] += 1
            c["feed_reps"] += reps
            c["feed_shift"] += sign * (after["x_mm"] - before["x_mm"])
    return c


def sum_plate_counts(runs: list[RunLog]) -> dict[str, float]:
    out: dict[str, float] = {}
    for r in runs:
        for k, v in plate_counts(r).items():
            out[k] = out.get(k, 0.0) + v
    return out


def _ratio(num: str, den: str) -> Callable[[dict[str, float]], float]:
    return lambda c: c[num] / max(c[den], 1e-9)


def _parted(c: dict[str, float]) -> float:
    """How well flips part the parts: new pickable parts a flip, over the share of the
    blobs after it that were rejected (touching). Both move with the flip's scatter (the
    first up, the second down); their ratio halves each one's scatter against it."""
    per_flip = c["after_new"] / max(c["flips"], 1e-9)
    rejected = c["after_rejected"] / max(c["after_blobs"], 1e-9)
    return per_flip / max(rejected, 1e-3)


PLATE_MOMENTS = (
    Moment("plate.dispense_per_rep", _ratio("held", "dispense_reps"), "held", 0.5, 0.25, 4.0,
           "parts picked per dispense repetition: {held:g} parts over {dispense_reps:g} "
           "repetitions"),
    Moment("plate.flip_scatter_mm", _parted, "after_new", 1.3, 0.25, 4.0,
           "the frames after {flips:g} flips: {after_new:g} new pickable parts, and "
           "{after_rejected:g} of {after_blobs:g} blobs rejected (touching)"),
    Moment("plate.feed_mm_per_rep", _ratio("feed_shift", "feed_reps"), "feeds", 0.8, 0.4, 2.5,
           "how far the blobs' mean place moved along the feed: {feed_shift:.0f} mm over "
           "{feed_reps:g} feed repetitions ({feeds:g} feeds)"),
)


def fit_action_time(runs: list[RunLog], cell: CellSpec) -> dict[str, Estimate]:
    """``plate.rep_s`` and ``plate.settle_s`` from the logged action times (least squares
    against the repetitions each action ran)."""
    rows = [(a["reps"] + (1 if a["action"] == "flip_forward" else 0), a["dt"])
            for r in runs for _, a in r.plate]
    nominal = {"plate.rep_s": cell.plate.rep_s, "plate.settle_s": cell.plate.settle_s}
    reps = {n for n, _ in rows}
    if len(rows) < MIN_COUNT or len(reps) < 2:
        why = (f"{len(rows)} timed plate actions at {len(reps)} repetition count(s): "
               f"at least {MIN_COUNT} at two or more needed")
        return {k: Estimate(v, None, why, fixed=False) for k, v in nominal.items()}
    x = np.array([[n, 1.0] for n, _ in rows], dtype=float)
    y = np.array([dt for _, dt in rows], dtype=float)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    res = y - x @ coef
    s2 = float(res @ res) / max(len(rows) - 2, 1)
    cov = s2 * np.linalg.pinv(x.T @ x)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    what = (f"{len(rows)} timed plate actions (command to the feeder's done) at "
            f"{', '.join(map(str, sorted(reps)))} repetitions; rms residual "
            f"{1000 * math.sqrt(s2):.1f} ms")
    out = {}
    for k, v, e in (("plate.rep_s", coef[0], sd[0]), ("plate.settle_s", coef[1], sd[1])):
        # the leaf sees the feeder's done at its next tick: a few ms the sd carries
        e = max(float(e), 1e-3)
        if v <= 0.0:
            out[k] = Estimate(nominal[k], None, f"the fit gave {v:.3f} s: {what}", fixed=False)
        else:
            out[k] = Estimate(float(v), e, what)
    return out


def fit_plate_twin(runs: list[RunLog], logs: list[str], cell: CellSpec, rounds: int,
                   seeds: tuple[int, ...], say: Callable[[str], None] | None,
                   scenario: str | None) -> Twin:
    """A plate cell's twin from its runs (see the module)."""
    est: dict[str, Estimate] = dict(fit_arm(runs, cell))
    est.update(fit_action_time(runs, cell))
    start = {_flat(k): e.value for k, e in est.items() if e.fixed}
    if say:
        say(f"arm: {len(moves(runs, cell))} timed moves; plate: "
            f"{sum(len(r.plate) for r in runs)} timed actions; " + ", ".join(
                f"{k} {e.value:.4g}" for k, e in est.items() if e.fixed))
    est.update(fit_moments(runs, cell, start, rounds, seeds, say, scenario,
                           moments=PLATE_MOMENTS, count=sum_plate_counts))
    return Twin(est, [str(p) for p in logs], str(cell.path), untested(runs, cell),
                not_fitted=dict(PLATE_NOT_FITTED))
