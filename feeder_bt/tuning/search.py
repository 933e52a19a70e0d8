"""The search loop of ``feeder tune``: Optuna asks, workers run, Optuna is told.

The study lives only in this process (its SQLite file is written by nobody else), and the
workers get plain jobs (one scenario run per seed) through any ``concurrent.futures``
executor: a process pool on this machine, a Dask cluster's executor, or this process
itself for one worker. A trial's value is the mean parts/min over its seeds (kits/min for a
scenario that builds kits: a part that completes no kit is worth nothing to an assembly);
every trial runs the same seeds 1..K, so trials differ only by their settings.

Short trials first (successive halving, ``rungs``): a trial runs a quarter of the duration
on seed 1, then the whole duration on seed 1, then the other seeds; after each rung but the
last it goes on only if its score is among the best ``1/eta`` of the scores at that rung so
far (the rule of Optuna's ``SuccessiveHalvingPruner``), else it is pruned. Most settings
are judged on a quarter of a run, so many more are tried in the same time; only the trials
that reach the last rung have a value, and the best is one of them. A setting over the wear
budget scores below every setting within it (its score is minus its excess), so the rungs
spend nothing on settings that flood the belt. With halving, a new study's first trials are
the scenario as written and then the same settings with each other pick policy: of all the
settings, the pick policy moved lenses' parts/min most (docs/performance.md), and these
cost a quarter run each where they do not pay.
"""

from __future__ import annotations

import concurrent.futures as cf
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from feeder_bt.config.loader import RETRIEVE_POLICIES
from feeder_bt.core.errors import FeederError
from feeder_bt.tuning.objective import Job, evaluate
from feeder_bt.tuning.space import GRID_MIN_TRIALS, Limits, grid_space, start_params, suggest

INTERRUPTED = "interrupted"


class TuneError(FeederError):
    """A study that cannot go on as asked (other duration or seeds than it was started with)."""

    exit_code = 2


@dataclass
class TuneConfig:
    scenario: str
    trials: int = 20
    duration: float = 600.0
    seeds: int = 2
    space: str = "ours"
    study: str | None = None            # SQLite file; None: in memory
    cell: str | None = None
    supply: str | None = None
    world: str | None = None            # tune on this world (a twin), not the cell's figures
    sampler_seed: int = 0
    # wear budget: recirculations per placed part a setting may cost; a trial
    # over it is infeasible (TPE's constraints), never the best
    max_recirc: float | None = None
    grid: bool = False                  # the fixed space as a grid (space.grid_space), not TPE
    halving: bool = False               # short trials first (``rungs``; the CLI's default)
    eta: int = 3                        # a rung keeps the best 1/eta
    minutes: float | None = None        # wall-clock budget of the whole command
    started: float | None = None        # time.monotonic() at the command's start (None: now)


#: of a ``minutes`` budget, what is kept for what is not the search: the interpreter's start
#: before the command's clock and the wrap-up after the last run (the pool's shutdown, the
#: summary); 2.7 s measured on the project's two cores, from a process 601 s long whose
#: search stopped 2 s inside a budget that did not count them
WRAP_UP_S = 5.0

#: the wear budget ``feeder tune`` searches under unless told otherwise: recirculations per
#: placed part (each pass wears the parts and the belt; unbudgeted, the simulator's best
#: settings flood the belt: 7 recirculations per placed part on lenses)
DEFAULT_MAX_RECIRC = 1.5


def rungs(cfg: TuneConfig) -> list[tuple[float, tuple[int, ...]]]:
    """(duration, the seeds it adds) of each rung: a quarter run on seed 1, the whole run
    on seed 1, the other seeds. Without halving, one rung: every seed, whole."""
    every = tuple(range(1, cfg.seeds + 1))
    if not cfg.halving or cfg.grid:
        return [(cfg.duration, every)]
    out = [(cfg.duration / 4.0, (1,)), (cfg.duration, (1,))]
    if cfg.seeds > 1:
        out.append((cfg.duration, every[1:]))
    return out


def score(ppm: float, recirc: float | None, budget: float | None) -> float:
    """What a rung ranks: parts/min within the wear budget, minus the excess over it (so
    below every setting within it) otherwise."""
    if budget is None:
        return ppm
    over = math.inf if recirc is None else recirc - budget
    return ppm if over <= 0 else -min(over, 1e9)


def promoted(value: float, scores: list[float], eta: int) -> bool:
    """Whether a trial scoring ``value`` at a rung (``scores``: every score there so far,
    its own included) goes on: it must be among the best ``len(scores) // eta`` (the best
    one while there are fewer than ``2 * eta``), as Optuna's successive halving rules."""
    keep = max(1, len(scores) // eta)
    return value >= sorted(scores, reverse=True)[keep - 1]


@dataclass
class TrialResult:
    """One finished trial, as the progress display and the tests see it."""

    number: int
    value: float | None                 # mean parts/min (kits/min for kits); None: failed
    per_seed: list[float] = field(default_factory=list)
    overlay: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    start: bool = False                 # the scenario as written (a new study's first trial)
    pruned_at: int | None = None        # the rung after which it stopped (successive halving)
    duration: float | None = None       # of the runs its value or score is over
    recirc: float | None = None         # recirculations per placed part, mean of the seeds
    feasible: bool = True               # within --max-recirc
    unit: str = "parts/min"             # what value counts (objective_unit)


def objective_unit(scenario: Any) -> str:
    """What a trial's value counts: kits/min when the scenario builds kits, else parts/min."""
    r = scenario.retrieve
    return "kits/min" if (r.kit or r.sequence) else "parts/min"


def unit_of(study: Any) -> str:
    """The unit a study's values are in (studies made before kits counted parts)."""
    return study.user_attrs.get("unit", "parts/min")


def recirc_over(trial: Any, budget: float | None) -> float:
    """How far a trial's recirculations per placed part exceed the budget (<= 0: within);
    a trial that placed nothing, or has no figure, is over any budget."""
    if budget is None:
        return 0.0
    r = trial.user_attrs.get("recirc_per_placed")
    return math.inf if r is None else r - budget


class InlineExecutor(cf.Executor):
    """Runs each job in this process when submitted: one worker without a process pool."""

    def submit(self, fn, /, *args, **kwargs):  # type: ignore[override]
        fut: cf.Future = cf.Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as e:  # noqa: BLE001 - handed to the caller like a pool would
            fut.set_exception(e)
        return fut


def study_name(cfg: TuneConfig) -> str:
    """One study per scenario, space and supply plan, so one file can hold the baselines."""
    name = f"{Path(cfg.scenario).stem}:{cfg.space}" + (":grid" if cfg.grid else "")
    name += f":{Path(cfg.supply).stem}" if cfg.supply else ""
    return name + (f":world={Path(cfg.world).stem}" if cfg.world else "")


def open_study(cfg: TuneConfig, read_only: bool = False, unit: str = "parts/min") -> Any:
    """Create the study, or load it to continue; refuses to mix durations or seeds."""
    import optuna
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = None
    if cfg.study:
        Path(cfg.study).parent.mkdir(parents=True, exist_ok=True)
        storage = f"sqlite:///{Path(cfg.study).resolve()}"
    name = study_name(cfg)
    try:
        study = optuna.create_study(study_name=name, storage=storage, direction="maximize",
                                    load_if_exists=True)
    except Exception as e:      # sqlalchemy / sqlite: a file that is not a study
        raise TuneError(f"{cfg.study}: cannot open as an Optuna study ({e})") from None
    want = {"duration_s": cfg.duration, "seeds": cfg.seeds, "space": cfg.space,
            "scenario": str(cfg.scenario), "supply": cfg.supply, "unit": unit,
            "max_recirc": cfg.max_recirc, "halving": cfg.halving and not cfg.grid}
    have = study.user_attrs
    if not have:
        for k, v in want.items():
            study.set_user_attr(k, v)
    else:
        for k in ("duration_s", "seeds", "unit"):
            if have.get(k, "parts/min" if k == "unit" else None) != want[k]:
                raise TuneError(f"{cfg.study}: study {name!r} was run with {k} "
                                f"{have.get(k)}, not {want[k]}: its values would not compare "
                                f"(give the same, or another --study file)")
    return study


def _sampler(cfg: TuneConfig, done: int) -> Any:
    """TPE, seeded so that a search is repeatable; a resumed one draws new points."""
    import warnings

    import optuna
    startup = max(3, min(10, cfg.trials // 3))
    with warnings.catch_warnings():     # multivariate and group are "experimental"
        warnings.simplefilter("ignore")
        # multivariate, grouped by the adjuster's own parameters: the speeds' joint effect
        # (the wear budget is a ridge in belt x incline) is what a search must find
        return optuna.samplers.TPESampler(seed=cfg.sampler_seed + done, constant_liar=True,
                                          n_startup_trials=startup, multivariate=True,
                                          group=True)


def finished(study: Any) -> list[Any]:
    """The trials that count against ``--trials``: completed, pruned or failed, not
    interrupted."""
    from optuna.trial import TrialState
    return [t for t in study.get_trials(
        deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED, TrialState.FAIL))
        if t.user_attrs.get("error") != INTERRUPTED]


@dataclass
class _Open:
    """A trial in flight: its rung, the runs it waits for, the results of each rung."""

    trial: Any
    overlay: dict[str, Any]
    rung: int = 0
    waiting: int = 0
    results: dict[int, list[dict[str, Any]]] = field(default_factory=dict)


def run_search(cfg: TuneConfig, executor: cf.Executor, capacity: int,
               on_start: Callable[[int, int, tuple[float, int] | None], None] | None = None,
               on_trial: Callable[[TrialResult], None] | None = None) -> Any:
    """Run trials until the study has ``cfg.trials`` finished ones; returns the study.

    ``capacity`` is how many runs to keep in flight (the workers). ``on_start(done, total,
    best)``
    is called once, ``on_trial`` after every trial (for the progress display).
    """
    from optuna.trial import TrialState

    from feeder_bt.config import load_scenario
    if cfg.grid and cfg.space != "fixed":
        raise TuneError(f"--grid searches the fixed space (two speeds), not {cfg.space!r}")
    if cfg.grid and cfg.trials < GRID_MIN_TRIALS:
        raise TuneError(f"--grid needs --trials {GRID_MIN_TRIALS} at least (two belt speeds "
                        f"by two incline speeds by every pick policy), got {cfg.trials}")
    scenario, cell = load_scenario(cfg.scenario, cfg.cell)      # a bad scenario: one line
    limits = Limits.of(scenario, cell)
    study = open_study(cfg, unit=objective_unit(scenario))
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study.tell(t.number, state=TrialState.FAIL)              # left by an interrupted run
    done = len(finished(study))
    todo = max(0, cfg.trials - done)
    if cfg.grid:        # every point of the grid queued once; a resumed study runs the rest
        import itertools

        import optuna
        if not study.trials:
            grid = grid_space(scenario, limits, cfg.trials)
            for point in itertools.product(*grid.values()):
                study.enqueue_trial(dict(zip(grid, point, strict=True)))
        study.sampler = optuna.samplers.RandomSampler(seed=cfg.sampler_seed)
        todo = min(todo, len(study.get_trials(deepcopy=False, states=(TrialState.WAITING,))))
    else:
        study.sampler = _sampler(cfg, len(study.trials))
        if not study.trials:                # a new study starts from the scenario as written
            start = start_params(scenario, cfg.space, limits)
            if start is not None:
                study.enqueue_trial(start, user_attrs={"start": "scenario"})
                if cfg.halving:     # then its neighbours in the pick policy (see the module)
                    for policy in RETRIEVE_POLICIES:
                        if policy != start.get("policy"):
                            study.enqueue_trial({**start, "policy": policy})
    if on_start:
        complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        best = max(complete, key=lambda t: t.value, default=None)
        on_start(done, cfg.trials, None if best is None else (best.value, best.number))
    scenario_path = str(Path(cfg.scenario).resolve())
    cell_path = str(Path(cfg.cell).resolve()) if cfg.cell else None
    supply = str(Path(cfg.supply).resolve()) if cfg.supply else None
    world = str(Path(cfg.world).resolve()) if cfg.world else None
    ladder = rungs(cfg)
    scores: dict[int, list[float]] = {k: [] for k in range(len(ladder))}
    for t in study.get_trials(deepcopy=False):      # a resumed study's rungs so far
        for step, v in t.intermediate_values.items():
            if step in scores:
                scores[step].append(v)
    t0 = time.monotonic() if cfg.started is None else cfg.started
    deadline = None if cfg.minutes is None else t0 + 60.0 * cfg.minutes - WRAP_UP_S
    pending: dict[cf.Future, int] = {}
    open_trials: dict[int, _Open] = {}
    asked = 0
    stop = False

    took: dict[float, float] = {}      # duration -> the longest wall time a run of it took
    started: dict[cf.Future, tuple[float, float]] = {}

    def out_of_time(rung: int = 0) -> bool:
        """No time left to run ``rung``'s runs: they would end after the deadline (judged
        by the longest such run so far, behind the runs already in flight)."""
        if deadline is None:
            return False
        now = time.monotonic()
        duration, seeds = ladder[rung]
        # a length not run yet: the runs so far scaled to it (a whole run takes about four
        # quarter runs), not nothing
        longest = took.get(duration) or max(
            (t * duration / d for d, t in took.items() if d > 0), default=0.0)
        need = longest * (1.0 + (len(pending) + len(seeds) - 1) // capacity)
        return now + need >= deadline

    def submit(ot: _Open) -> None:
        duration, seeds = ladder[ot.rung]
        ot.waiting = len(seeds)
        for seed in seeds:
            job = Job(scenario_path, ot.overlay, seed, duration, cell_path, supply, world)
            t_submit = time.monotonic()         # before: an inline executor runs it here
            fut = executor.submit(evaluate, job)
            pending[fut] = ot.trial.number
            started[fut] = (duration, t_submit)

    try:
        while (asked < todo and not stop and not out_of_time()) or pending:
            while (asked < todo and not stop and not out_of_time()
                   and len(pending) < capacity):
                trial = study.ask()
                overlay = suggest(trial, cfg.space, limits)
                trial.set_user_attr("overlay", overlay)
                ot = open_trials[trial.number] = _Open(trial, overlay)
                submit(ot)
                asked += 1
            done_now, _ = cf.wait(list(pending), return_when=cf.FIRST_COMPLETED)
            for fut in done_now:
                number = pending.pop(fut)
                duration, t_start = started.pop(fut)
                took[duration] = max(took.get(duration, 0.0), time.monotonic() - t_start)
                try:
                    res = fut.result()
                except Exception as e:  # noqa: BLE001 - a worker died: the trial failed
                    res = {"error": f"worker: {type(e).__name__}: {e}"}
                if res.get("interrupted"):
                    stop = True
                ot = open_trials[number]
                ot.results.setdefault(ot.rung, []).append(res)
                ot.waiting -= 1
                if ot.waiting:
                    continue
                result = _rung_done(study, ot, ladder, scores, cfg,
                                    cut=stop or (ot.rung + 1 < len(ladder)
                                                 and out_of_time(ot.rung + 1)))
                if result is None:          # promoted: the next rung's runs
                    ot.rung += 1
                    submit(ot)
                    continue
                del open_trials[number]
                if on_trial:
                    on_trial(result)
    except KeyboardInterrupt:
        stop = True
    if stop:                    # Ctrl-C: unfinished trials fail, a rerun does them again
        for fut in pending:
            fut.cancel()
        for ot in open_trials.values():
            ot.trial.set_user_attr("error", INTERRUPTED)
            study.tell(ot.trial, state=TrialState.FAIL)
        raise KeyboardInterrupt
    return study


def _rung_done(study: Any, ot: _Open, ladder: list[tuple[float, tuple[int, ...]]],
               scores: dict[int, list[float]], cfg: TuneConfig, cut: bool
               ) -> TrialResult | None:
    """A trial's rung is done: told (its last rung), pruned, or None: it goes on."""
    from optuna.trial import TrialState
    results = ot.results[ot.rung]
    last = ot.rung == len(ladder) - 1
    errors = [r["error"] for r in results if r.get("error")]
    if last or errors:                  # the whole runs of every rung: the trial's value
        whole = [r for k, rs in ot.results.items() if ladder[k][0] == cfg.duration
                 for r in rs]
        return _tell(study, ot.trial, ot.overlay, results if errors else whole,
                     cfg.max_recirc)
    unit = unit_of(study)
    per_seed = [r["kpm"] if unit == "kits/min" else r["ppm"] for r in results]
    recirc = [r.get("recirc_per_placed") for r in results]
    mean_recirc = statistics.mean(recirc) if None not in recirc else None
    value = statistics.mean(per_seed)
    s = score(value, mean_recirc, cfg.max_recirc)
    ot.trial.report(s, ot.rung)
    scores[ot.rung].append(s)
    start = ot.trial.user_attrs.get("start") == "scenario"
    if not cut and (start or promoted(s, scores[ot.rung], cfg.eta)):
        return None
    # pruned: what it showed, for the progress line and for TPE (which ranks pruned
    # trials by how far they got and their score there)
    ot.trial.set_user_attr("per_seed_ppm", per_seed)
    ot.trial.set_user_attr("recirc_per_placed", mean_recirc)
    ot.trial.set_user_attr("pruned_duration_s", ladder[ot.rung][0])
    if cfg.max_recirc is not None:
        ot.trial.set_constraint("max_recirc", min(
            math.inf if mean_recirc is None else mean_recirc - cfg.max_recirc, 1e9))
    study.tell(ot.trial, state=TrialState.PRUNED)
    return TrialResult(ot.trial.number, value, per_seed, ot.overlay, start=start,
                       recirc=mean_recirc,
                       feasible=recirc_over(ot.trial, cfg.max_recirc) <= 0, unit=unit,
                       pruned_at=ot.rung, duration=ladder[ot.rung][0])


def _tell(study: Any, trial: Any, overlay: dict[str, Any],
          results: list[dict[str, Any]], budget: float | None = None) -> TrialResult:
    from optuna.trial import TrialState
    results.sort(key=lambda r: r.get("seed", 0))
    start = trial.user_attrs.get("start") == "scenario"
    errors = [r["error"] for r in results if r.get("error")]
    if errors:
        trial.set_user_attr("error", errors[0])
        study.tell(trial, state=TrialState.FAIL)
        return TrialResult(trial.number, None, overlay=overlay, error=errors[0], start=start)
    unit = unit_of(study)
    per_seed = [r["kpm"] if unit == "kits/min" else r["ppm"] for r in results]
    trial.set_user_attr("per_seed_ppm", per_seed)
    ceiling = [r.get("ceiling_ppm") or r.get("robot_bound_ppm") for r in results]
    if all(ceiling):
        trial.set_user_attr("ceiling_ppm", statistics.mean(ceiling))
    recirc = [r.get("recirc_per_placed") for r in results]
    mean_recirc = statistics.mean(recirc) if None not in recirc else None
    trial.set_user_attr("recirc_per_placed", mean_recirc)
    if budget is not None:              # TPE samples away from infeasible trials
        trial.set_constraint("max_recirc", min(recirc_over(trial, budget), 1e9))
    value = statistics.mean(per_seed)
    study.tell(trial, value)
    return TrialResult(trial.number, value, per_seed, overlay, start=start, recirc=mean_recirc,
                       feasible=recirc_over(trial, budget) <= 0, unit=unit)


def best_overlay(study: Any, max_recirc: float | None = None) -> tuple[dict[str, Any], Any]:
    """The best trial within the wear budget: its overlay and the trial. A study without a
    finished trial, or none within the budget, is an error."""
    from optuna.trial import TrialState
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not complete:
        raise TuneError(f"study {study.study_name!r} has no completed trial yet")
    within = [t for t in complete if recirc_over(t, max_recirc) <= 0]
    if not within:
        least = min(t.user_attrs.get("recirc_per_placed") or math.inf for t in complete)
        raise TuneError(f"study {study.study_name!r}: no trial within --max-recirc "
                        f"{max_recirc:g} (the least was {least:.2f} per placed part)")
    best = max(within, key=lambda t: t.value)
    return best.user_attrs["overlay"], best


def describe(overlay: dict[str, Any]) -> str:
    """A short name of an overlay's settings for progress lines: adjuster + policy."""
    adj = (overlay.get("adjust") or {}).get("algorithm", "?")
    pol = (overlay.get("retrieve") or {}).get("policy")
    present = overlay.get("present") or {}
    text = adj + (f" + {pol}" if pol else "")
    if adj == "none" and present:
        text += (f" belt {present.get('horizontal_mm_s'):g} mm/s, incline "
                 f"{present.get('incline_pct'):g} %")
    return text
