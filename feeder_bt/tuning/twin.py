"""A twin: world figures fitted from a cell's own event logs (``feeder twin fit``).

A cell's log holds what a real cell records: frames with their finds and rejected blobs
(reason, area, place), timed picks (where from, where to, at what speed, how they ended),
timed places, the belts' speeds and the faults. Nothing in it is the simulator's truth, so
a log of a real cell fits the same way as a simulated one's.

Two kinds of fit:

- **directly from the log**: the arm's joint limits. Every timed place and every pick that
  found its part in reach is a move between known points at a known speed; the SCARA's
  arch time (``robot/scara.py``, the cell's reach and base) is fitted to them by
  Gauss-Newton on the logarithms of joint 1's and joint 2's speeds and a common scale of
  their accelerations. Its uncertainty is the fit's (residual scatter through the
  Jacobian).
- **by simulated moments**: the hopper's release, the return transit, the clumping scale and
  the grip curve's width set counts the log has (parts located per mm the incline ran;
  how far that falls once parts come back; blobs no class takes; missed grabs). The twin
  simulates the logged run itself — the same scenario, settings and length, the controller
  reading only the cell file — and moves each figure until the simulated counts match the
  logged ones (a few rounds of ratio updates: each count is monotone in its figure). Each
  figure's uncertainty is its count's Poisson error carried through the count's
  sensitivity to it (the model's own for the release, measured between rounds for the
  rest).

A figure is left at the cell file's value, with the reason, when the log cannot fix it:
a count too small, a speed never varied, an effect the cell never reached.

A plate cell (``presentation: plate``) fits its plate's figures instead of the belt's
(``tuning/twin_plate.py``); the arm is fitted the same way.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sqlite3
import tempfile
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from feeder_bt.core.errors import FeederError
from feeder_bt.core.model import CellSpec
from feeder_bt.robot.scara import ScaraModel, arm_figures, world_arm

#: a located part counts as early when it left the hopper before any part could come back
#: (its first located part plus this long; a return takes a horizontal pass and the return)
EARLY_S = 30.0
#: the loop is full (parts returning, the hopper's fill steady) after this long
LATE_AFTER_S = 150.0
#: rounds of simulated moments, and the seeds each round simulates
ROUNDS = 4
SEEDS = (101, 102)
#: a count below this cannot fix its figure (its Poisson error would be over 30 %)
MIN_COUNT = 10
#: how far one round may move a figure (a factor): the counts are noisy
MAX_STEP = 2.0
#: a figure known no better than this (relative standard uncertainty) is not fixed
MAX_REL_SD = 0.3
#: ... and an arm's joint known no better than this (a data sheet's figure is closer)
MAX_ARM_REL_SD = 0.1


class TwinError(FeederError):
    """A log cannot be fitted: not a feeder log, no runs, no moves."""

    exit_code = 2


@dataclass
class RunLog:
    """What one logged run holds that a fit reads (all of it a real cell records)."""

    path: str
    run_id: int
    options: dict[str, Any]
    frames: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    picks: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    places: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    speeds: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    plate: list[tuple[float, dict[str, Any]]] = field(default_factory=list)  # actions done
    t_end: float = 0.0

    @property
    def t0(self) -> float:
        """When the belts first ran."""
        return self.speeds[0][0] if self.speeds else 0.0


def read_logs(paths: list[str]) -> list[RunLog]:
    """Every run of every event log named (a log missing or not ours: TwinError)."""
    from feeder_bt.records.eventlog import EventLogError, open_readonly
    runs: list[RunLog] = []
    for path in paths:
        try:
            conn = open_readonly(path)
        except EventLogError as e:
            raise TwinError(str(e)) from None
        try:
            for row in conn.execute("SELECT id, options FROM runs ORDER BY id"):
                run = RunLog(path, row["id"], json.loads(row["options"] or "{}"))
                for t, kind, data in conn.execute(
                        "SELECT t, kind, data FROM events WHERE run_id=? AND kind IN "
                        "('frame', 'pick', 'place', 'speeds', 'plate_done') ORDER BY t",
                        (row["id"],)):
                    getattr(run, {"frame": "frames", "pick": "picks", "place": "places",
                                  "speeds": "speeds", "plate_done": "plate"}[kind]).append(
                        (t, json.loads(data)))
                end = conn.execute("SELECT MAX(t) FROM samples WHERE run_id=?",
                                   (row["id"],)).fetchone()[0]
                run.t_end = float(end or 0.0)
                if run.frames:
                    runs.append(run)
        except sqlite3.Error as e:
            raise TwinError(f"{path}: cannot read the event log: {e}") from None
        finally:
            conn.close()
    if not runs:
        raise TwinError(f"{', '.join(paths)}: no run with logged frames (a log written "
                        "before frames were logged cannot be fitted)")
    return runs


# ============================================================================ counts

def _incline_travel(run: RunLog, a: float, b: float) -> float:
    """mm the incline ran between times ``a`` and ``b`` (its commanded speeds, logged at
    every change; ramps are short against a run)."""
    travel, speed, t_prev = 0.0, 0.0, run.t0
    for t, d in run.speeds:
        lo, hi = max(t_prev, a), min(t, b)
        if hi > lo:
            travel += speed * (hi - lo)
        speed, t_prev = float(d.get("incline_mm_s", 0.0)), t
    lo, hi = max(t_prev, a), b
    if hi > lo:
        travel += speed * (hi - lo)
    return travel


def counts(run: RunLog) -> dict[str, float]:
    """The counts the simulated-moments fit matches (each from the log alone). Parts
    located are set against the incline's travel that brought them (shifted by the time
    the first part took to arrive), so the belt speeds the adjuster chose cancel."""
    located = [(t, f["new"]) for t, f in run.frames if f["new"]]
    first = located[0][0] if located else run.t0
    lag = first - run.t0
    early = sum(n for t, n in located if t <= first + EARLY_S)
    late_from = run.t0 + LATE_AFTER_S
    late = sum(n for t, n in located if t >= late_from)
    blobs = sum(f["parts"] + len(f["rejected"]) for _, f in run.frames)
    no_class = sum(1 for _, f in run.frames for b in f["rejected"] if b[0] == "no class")
    picks = len(run.picks)
    missed = sum(1 for _, p in run.picks if p["outcome"] == "missed_grab")
    return {"located": float(sum(n for _, n in located)),
            "travel": _incline_travel(run, run.t0, run.t_end - lag),
            "early": float(early), "early_travel": _incline_travel(run, run.t0, run.t0 + EARLY_S),
            "late": float(late),
            "late_travel": _incline_travel(run, late_from - lag, run.t_end - lag),
            "blobs": float(blobs), "no_class": float(no_class),
            "picks": float(picks), "missed": float(missed)}


def _sum_counts(runs: list[RunLog]) -> dict[str, float]:
    out: dict[str, float] = {}
    for r in runs:
        for k, v in counts(r).items():
            out[k] = out.get(k, 0.0) + v
    return out


# ============================================================================ the arm

@dataclass
class Move:
    """One timed move of the arm: from, to, speed %, the arch's time (s)."""

    a: tuple[float, float]
    b: tuple[float, float]
    speed: float
    t: float


def moves(runs: list[RunLog], cell: CellSpec) -> list[Move]:
    """The arch times in the logs: every place, and every held pick that was in reach when
    commanded (the others may have waited for their part). What the cell adds to the arch
    (command overhead, grip or release, tracking's settle) is the cell file's."""
    r = cell.robot
    out: list[Move] = []
    for run in runs:
        for _, p in run.places:
            out.append(Move((p["x0"], p["y0"]), (p["x"], p["y"]), p["speed"],
                            p["dt"] - r.command_overhead_s - r.release_s))
        for _, p in run.picks:
            if p["outcome"] != "held" or not p["usable"] or p["grip_x"] is None:
                continue
            hold = (r.track_settle_s if p["tracking"] else 0.0) + r.grip_s
            x = p["grip_x"] - (p["belt_mm_s"] * hold if p["tracking"] else 0.0)
            out.append(Move((p["x0"], p["y0"]), (x, p["y"]), p["speed"],
                            p["dt"] - r.command_overhead_s - hold))
    return out


def _arm(cell: CellSpec, theta: np.ndarray) -> ScaraModel:
    """The cell's nominal arm with joint 1's and 2's speeds and their accelerations scaled
    by exp(theta) = (v1, v2, acceleration)."""
    base = world_arm(cell.robot).scara
    f1, f2, fa = np.exp(theta)
    spec = dataclasses.replace(base, j1_rad_s=base.j1_rad_s * f1, j2_rad_s=base.j2_rad_s * f2,
                               j1_rad_s2=base.j1_rad_s2 * fa, j2_rad_s2=base.j2_rad_s2 * fa)
    return ScaraModel(cell.robot, spec)


def _predict(cell: CellSpec, theta: np.ndarray, ms: list[Move]) -> np.ndarray:
    arm = _arm(cell, theta)
    return np.array([arm.move_time(m.a, m.b, m.speed) for m in ms])


@dataclass
class Estimate:
    """One world figure: its value, standard uncertainty, and what fixed it (or why not)."""

    value: float
    sd: float | None
    fixed_by: str
    fixed: bool = True


def fit_arm(runs: list[RunLog], cell: CellSpec) -> dict[str, Estimate]:
    """Joint 1's and 2's speeds and accelerations from the logged arch times."""
    ms = moves(runs, cell)
    nominal = arm_figures(world_arm(cell.robot).scara)
    keys = ("arm_j1_deg_s", "arm_j2_deg_s", "arm_j1_deg_s2", "arm_j2_deg_s2")
    if len(ms) < 3 * MIN_COUNT:
        why = f"only {len(ms)} timed moves in the log (at least {3 * MIN_COUNT} needed)"
        return {k: Estimate(nominal[k] if k in nominal else cell.sim.robot_time_cv, None, why,
                            fixed=False) for k in (*keys, "sim.robot_time_cv")}
    y = np.array([m.t for m in ms])
    theta = np.zeros(3)
    for _ in range(12):                   # Gauss-Newton, numeric Jacobian
        f = _predict(cell, theta, ms)
        jac = np.empty((len(ms), 3))
        for j in range(3):
            d = np.zeros(3)
            d[j] = 1e-4
            jac[:, j] = (_predict(cell, theta + d, ms) - f) / 1e-4
        step, *_ = np.linalg.lstsq(jac, y - f, rcond=None)
        theta = theta + np.clip(step, -0.5, 0.5)
        if np.max(np.abs(step)) < 1e-5:
            break
    f = _predict(cell, theta, ms)
    res = y - f
    s2 = float(res @ res) / max(len(ms) - 3, 1)
    norms = np.linalg.norm(jac, axis=0)
    live = norms > 1e-6 * max(float(norms.max()), 1e-12)   # a joint that never limited
    sd = np.full(3, math.inf)
    if live.any():
        jl = jac[:, live]
        sd[live] = np.sqrt(np.maximum(np.diag(s2 * np.linalg.pinv(jl.T @ jl)), 0.0))
    speeds = sorted({round(m.speed) for m in ms})
    what = (f"{len(ms)} timed moves (places, and picks in reach) at robot speed "
            f"{', '.join(map(str, speeds))} %; rms residual {1000 * math.sqrt(s2):.1f} ms")
    fitted = arm_figures(_arm(cell, theta).scara)
    out = {}
    for k, j in (("arm_j1_deg_s", 0), ("arm_j2_deg_s", 1), ("arm_j1_deg_s2", 2),
                 ("arm_j2_deg_s2", 2)):
        # a joint that never limited a move has a flat direction: its error says so
        rel = float(sd[j])
        if not math.isfinite(rel):
            out[k] = Estimate(nominal[k], None, "no logged move depended on it (the other "
                              f"joint was always the slower): {what}", fixed=False)
        elif rel > MAX_ARM_REL_SD:
            out[k] = Estimate(nominal[k], None, f"the logged moves hardly depend on it "
                              f"(fit error {rel:.0%}): {what}", fixed=False)
        else:
            out[k] = Estimate(fitted[k], fitted[k] * rel, what)
    # the moves' scatter about the fitted arm: the world's per-move noise (what the arm
    # model misses would add to it)
    cv = float(np.std(res / np.maximum(f, 1e-3)))
    out["sim.robot_time_cv"] = Estimate(cv, cv / math.sqrt(2.0 * len(ms)),
                                        f"the scatter of {len(ms)} timed moves about the "
                                        "fitted arm (what the arm model misses would add "
                                        "to it)")
    return out


# ============================================================================ simulated moments

def _yaml_value(v: float) -> float:
    return float(f"{v:.6g}")


def world_yaml(figures: dict[str, float]) -> dict[str, Any]:
    """A world file's data from flat figures (``hopper.release_per_mm``, ``sim.x``...)."""
    out: dict[str, Any] = {}
    for key, v in figures.items():
        if key == "return_transit_s":
            out.setdefault("conveyors", {}).setdefault("return", {})["transit_s"] = \
                _yaml_value(v)
            continue
        section, _, name = key.partition(".")
        out.setdefault(section, {})[name] = _yaml_value(v)
    return out


def logged_files(run: RunLog, scenario: str | None = None) -> tuple[str, str | None]:
    """The scenario and overlay the logged run ran (``scenario`` instead, if given): the
    twin runs them again. A log names them as its run was given them, maybe relative to
    another folder: one not found here is a TwinError that says how to give it."""
    o = run.options
    scen = scenario or o.get("scenario_file")
    if not scen or not Path(scen).is_file():
        raise TwinError(f"{run.path}: run {run.run_id}'s scenario {scen!r} is not found from "
                        "here; name it with --scenario")
    overlay = o.get("overlay")
    if overlay and not Path(overlay).is_file():
        raise TwinError(f"{run.path}: run {run.run_id}'s overlay {overlay!r} is not found "
                        "from here")
    return scen, overlay


def simulate(run: RunLog, cell: CellSpec, figures: dict[str, float],
             seeds: tuple[int, ...] = SEEDS, scenario: str | None = None) -> list[RunLog]:
    """The logged run again on a world with ``figures`` (and nothing else of the log's
    world: a plant's own world file is what is being found), one per seed; the controller
    reads ``cell``'s file, the cell file the fit was given."""
    from feeder_bt.app.run import RunOptions, run_job
    scen, overlay = logged_files(run, scenario)
    duration = run.options.get("duration") or max(run.t_end - run.t0, 1.0)
    out: list[RunLog] = []
    with tempfile.TemporaryDirectory() as tmp:
        world = Path(tmp) / "world.yaml"
        world.write_text(yaml.safe_dump(world_yaml(figures), sort_keys=False))
        for seed in seeds:
            db = Path(tmp) / f"sim{seed}.db"
            run_job(RunOptions(scenario=scen, cell=str(cell.path), duration=duration,
                               fast=True, seed=seed, view="none", db=str(db),
                               overlay=overlay, world=str(world)))
            out.extend(read_logs([str(db)]))
    return out


@dataclass
class Moment:
    """A figure fitted by matching one statistic of the counts to the log's."""

    key: str                  # flat figure key (world_yaml's)
    stat: Callable[[dict[str, float]], float]
    count: str                # the count whose Poisson error sets the uncertainty
    elasticity: float         # d ln(stat) / d ln(figure), a first guess (then measured)
    lo: float                 # the search's bounds, as factors of the cell file's value
    hi: float
    what: str                 # what in the log fixes it
    measured: bool = True     # False: the elasticity is the model's own (not a secant)


def _per(num: str, den: str) -> Callable[[dict[str, float]], float]:
    return lambda c: c[num] / max(c[den], 1e-9)


def _fill_drop(c: dict[str, float]) -> float:
    """Parts per mm of lift once the loop is full, against the first parts': below 1 when
    the hopper ran under its nominal fill (then the return transit sets the release)."""
    return (c["late"] / max(c["late_travel"], 1e-9)) / max(c["early"] / max(c["early_travel"],
                                                                            1e-9), 1e-9)


MOMENTS = (
    Moment("hopper.release_per_mm", _per("located", "travel"), "located", 1.0, 0.25, 4.0,
           "parts located per mm the incline ran: {located:g} parts over {travel:.0f} mm",
           measured=False),      # the hopper releases in proportion: elasticity 1
    Moment("return_transit_s", _fill_drop, "late", -0.5, 0.5, 2.0,
           "parts located per mm of lift once the loop was full (after {late_s:g} s) "
           "against the first {early_s:g} s's: {late:g} and {early:g} parts"),
    Moment("sim.clump_cover_scale", _per("no_class", "blobs"), "no_class", -0.5, 0.1, 10.0,
           "blobs no class took (merged parts) against all blobs: {no_class:g} of {blobs:g}"),
    Moment("sim.grip_width_mm", _per("missed", "picks"), "missed", 1.5, 0.1, 10.0,
           "missed grabs against picks: {missed:g} of {picks:g}"),
)


def _not_fixed(m: Moment, obs: dict[str, float], sim: dict[str, float]) -> str | None:
    """Why ``m``'s figure cannot be fixed by these logs, or None."""
    n = obs[m.count]
    if n < MIN_COUNT:
        return f"only {n:g} {m.count.replace('_', ' ')} in the log (at least {MIN_COUNT} needed)"
    if m.key == "return_transit_s":
        noise = math.sqrt(1.0 / max(obs["early"], 1.0) + 1.0 / max(obs["late"], 1.0))
        drop = _fill_drop(obs)
        if drop > 1.0 - 2.5 * noise:
            return (f"parts per mm of lift once the loop was full were {drop:.2f} of the "
                    f"first's (±{noise:.2f}): no clear fall, so the hopper did not run below "
                    "its nominal fill at the logged settings and the return transit never "
                    "set the release")
    return None


def fit_moments(runs: list[RunLog], cell: CellSpec, start: dict[str, float],
                rounds: int = ROUNDS, seeds: tuple[int, ...] = SEEDS,
                say: Callable[[str], None] | None = None,
                scenario: str | None = None,
                moments: tuple[Moment, ...] = MOMENTS,
                count: Callable[[list[RunLog]], dict[str, float]] | None = None
                ) -> dict[str, Estimate]:
    """The simulated-moments figures (``moments``, the belt's ``MOMENTS`` unless given,
    matched on ``count``'s counts), from ``start`` (the arm's already)."""
    count = count or _sum_counts
    obs = count(runs)
    fig = dict(start)
    nominal = {m.key: _cell_figure(cell, m.key) for m in moments}
    fig.update(nominal)
    hist: dict[str, list[tuple[float, float]]] = {m.key: [] for m in moments}
    # each round's figure: the last ones averaged, so one round's simulated scatter does
    # not decide the figure (a stochastic approximation's iterate average)
    proposals: dict[str, list[float]] = {m.key: [] for m in moments}
    frozen: dict[str, str] = {}
    for rnd in range(rounds):
        # every logged run again, each with its own settings and length
        sc = count([sim for run in runs for sim in simulate(run, cell, fig, seeds, scenario)])
        for m in moments:
            if m.key in frozen:
                continue
            why = _not_fixed(m, obs, sc)
            if why is not None:
                frozen[m.key] = why
                fig[m.key] = nominal[m.key]
                continue
            s_obs, s_sim = m.stat(obs), m.stat(sc)
            if s_obs <= 0.0 or s_sim <= 0.0:
                continue
            hist[m.key].append((math.log(fig[m.key]), math.log(s_sim)))
            e = _elasticity(hist[m.key], m.elasticity) if m.measured else m.elasticity
            step = math.exp(max(-math.log(MAX_STEP),
                                min(math.log(MAX_STEP), math.log(s_obs / s_sim) / e)))
            fig[m.key] = min(m.hi * nominal[m.key], max(m.lo * nominal[m.key],
                                                         fig[m.key] * step))
            proposals[m.key].append(fig[m.key])
        if say:
            say(f"round {rnd + 1}: " + ", ".join(f"{k.split('.')[-1]} {fig[k]:.4g}"
                                                 for k in nominal if k not in frozen))
    out: dict[str, Estimate] = {}
    for m in moments:
        if m.key in frozen:
            out[m.key] = Estimate(nominal[m.key], None, frozen[m.key], fixed=False)
            continue
        e = _elasticity(hist[m.key], m.elasticity) if m.measured else m.elasticity
        # the log's count and the simulated ones (as many per seed, averaged over the
        # rounds after the first) both scatter
        rounds_avg = max(len(proposals[m.key]) - 1, 1)
        rel = math.sqrt(1.0 / max(obs[m.count], 1.0)
                        * (1.0 + 1.0 / (len(seeds) * rounds_avg))) / max(abs(e), 0.05)
        what = m.what.format(early_s=EARLY_S, late_s=LATE_AFTER_S, **obs)
        tail = proposals[m.key][1:] or proposals[m.key] or [fig[m.key]]
        fig[m.key] = math.exp(sum(math.log(v) for v in tail) / len(tail))
        if rel > MAX_REL_SD:
            out[m.key] = Estimate(nominal[m.key], None, (
                f"the log fixes it only to ±{rel:.0%} (its count moves as the figure to the "
                f"power {e:+.2f}: {what})"), fixed=False)
            continue
        out[m.key] = Estimate(fig[m.key], fig[m.key] * rel,
                              f"{what}; d ln(count) / d ln(figure) {e:+.2f}")
    return out


def _elasticity(hist: list[tuple[float, float]], guess: float) -> float:
    """d ln(count) / d ln(figure) from the rounds so far (a secant), else the guess; kept
    to the guess's sign and not below a fifth of it, so one noisy round cannot flip it."""
    if len(hist) >= 2:
        (x0, y0), (x1, y1) = hist[-2], hist[-1]
        if abs(x1 - x0) > 0.02:
            e = (y1 - y0) / (x1 - x0)
            if e * guess > 0:
                return math.copysign(max(abs(e), abs(guess) / 5.0), guess)
    return guess


def _cell_figure(cell: CellSpec, key: str) -> float:
    if key == "return_transit_s":
        return cell.return_transit_s
    section, _, name = key.partition(".")
    return float(getattr(getattr(cell, section), name))


# ============================================================================ the twin

NOT_FITTED = {
    "sim.belt_mu_static": "a slide is invisible to the encoder and the log records no "
                          "slide: the log only says the belt's acceleration never slid a "
                          "part that was then missed",
    "sim.belt_mu_kinetic": "as belt_mu_static: no slide in the log",
    "hopper.nominal_fill": "the release's fall with the fill is fitted through the return "
                           "transit; the hopper's fill is not recorded, so the two cannot "
                           "be told apart from one lift speed",
    "arm_z_mm_s": "every arch has the same vertical legs: their time cannot be told from "
                  "the grip and release times",
    "sim.grip_p_centre": "misses are fitted through the grip curve's width: a log cannot "
                         "tell a miss over the part's centre from one off it (the cup's "
                         "offset from the true part is not recorded)",
}


@dataclass
class Twin:
    """The fitted world figures, and what could not be fitted."""

    estimates: dict[str, Estimate]
    logs: list[str]
    cell: str
    untested: dict[str, str] = field(default_factory=dict)   # assumptions the log never tried
    not_fitted: dict[str, str] = field(default_factory=lambda: dict(NOT_FITTED))

    def figures(self) -> dict[str, float]:
        """The world file's figures: every estimate the log fixed."""
        return {_flat(k): e.value for k, e in self.estimates.items() if e.fixed}

    def notes(self) -> dict[str, Any]:
        fitted = {k: {"estimate": _yaml_value(e.value),
                      "sd": None if e.sd is None else _yaml_value(e.sd),
                      "fixed_by": e.fixed_by}
                  for k, e in self.estimates.items() if e.fixed}
        unfixed = {k: e.fixed_by for k, e in self.estimates.items() if not e.fixed}
        unfixed.update(self.not_fitted)
        unfixed.update(self.untested)
        return {"logs": self.logs, "cell": self.cell, "fitted": fitted, "not_fixed": unfixed}

    def write(self, path: str | Path) -> None:
        data = world_yaml(self.figures())
        data["fit"] = self.notes()
        text = ("# A twin: world figures fitted from event logs (feeder twin fit); the\n"
                "# controller still reads the cell file. fit: says what fixed each figure.\n")
        text += yaml.safe_dump(data, sort_keys=False, width=100)
        p = Path(path)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(text, encoding="utf-8")
        except OSError as e:
            raise TwinError(f"{path}: cannot write the twin: {e.strerror or e}") from None


def _flat(key: str) -> str:
    """An arm figure's world key (``sim.arm_...``); the rest are flat already."""
    return f"sim.{key}" if key.startswith("arm_") else key


def fit_twin(logs: list[str], cell: CellSpec, rounds: int = ROUNDS,
             seeds: tuple[int, ...] = SEEDS,
             say: Callable[[str], None] | None = None, scenario: str | None = None) -> Twin:
    """Fit a twin of ``cell`` from the runs in ``logs`` (see the module); ``scenario``:
    the scenario they ran, when the logs' own path to it does not hold here."""
    runs = read_logs(logs)
    for run in runs:                       # before any fitting: a missing file fails now
        logged_files(run, scenario)
    if cell.presentation == "plate":
        from feeder_bt.tuning.twin_plate import fit_plate_twin
        return fit_plate_twin(runs, logs, cell, rounds, seeds, say, scenario)
    arm = fit_arm(runs, cell)
    start = {_flat(k): e.value for k, e in arm.items() if e.fixed}
    if say:
        say(f"arm: {len(moves(runs, cell))} timed moves; " + ", ".join(
            f"{k} {e.value:.4g}" for k, e in arm.items() if e.fixed))
    est: dict[str, Estimate] = dict(arm)
    est.update(fit_moments(runs, cell, start, rounds, seeds, say, scenario))
    return Twin(est, [str(p) for p in logs], str(cell.path), untested(runs, cell))


def untested(runs: list[RunLog], cell: CellSpec) -> dict[str, str]:
    """The model's assumptions a figure rests on that the logs never varied."""
    out: dict[str, str] = {}
    speeds = sorted({round(m.speed) for m in moves(runs, cell)})
    if len(speeds) < 2:
        out["robot speed %"] = (f"every logged move ran at {speeds[0] if speeds else '?'} %: "
                                "the arm's times at other speeds rest on the model's 1/speed")
    lift = [float(d.get("incline_mm_s", 0.0)) for r in runs for _, d in r.speeds
            if d.get("incline_mm_s")]
    if lift and max(lift) < 1.2 * min(lift):
        out["release with lift speed"] = (
            f"the incline ran only at {min(lift):g}-{max(lift):g} mm/s: the release at other "
            "lift speeds rests on the model's release per mm of travel")
    return out
