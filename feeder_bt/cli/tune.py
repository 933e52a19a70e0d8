"""``feeder tune SCENARIO``: search belt and incline speeds, frame spacing, the adjuster and
its parameters and the pick policy for the best mean parts/min over K seeds of a simulated
run, with Optuna; write the best settings as an overlay for ``feeder run --overlay``."""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import multiprocessing
import os
import sys
import time
from collections import Counter
from contextlib import ExitStack
from typing import Any

from feeder_bt.cli.argtypes import non_negative, positive, positive_int
from feeder_bt.core.errors import FeederError
from feeder_bt.tuning.search import DEFAULT_MAX_RECIRC
from feeder_bt.tuning.space import SPACES

DEFAULT_STUDY = "runs/tune.db"


class TuneUsage(FeederError):
    exit_code = 2


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``tune`` on the ``feeder`` sub-command parsers."""
    p = subparsers.add_parser(
        "tune", help="search a scenario's speeds, adjuster and pick policy for the best "
                     "parts/min (simulated, virtual time); write the best as an overlay")
    p.add_argument("scenario", help="scenario YAML, e.g. scenarios/lenses.yaml")
    p.add_argument("--trials", type=positive_int, default=20,
                   help="trials in the study in all (a rerun continues to this many; "
                        "default 20)")
    p.add_argument("--duration", type=positive, default=600.0,
                   help="simulated seconds per run (default 600)")
    p.add_argument("--seeds", type=positive_int, default=2,
                   help="runs per trial, seeds 1..K; the trial's value is their mean "
                        "parts/min (default 2)")
    p.add_argument("--workers", type=positive_int, default=None,
                   help="local worker processes (default: the machine's cores; 1 runs the "
                        "trials in this process)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run the trials on a Dask cluster's workers, e.g. "
                        "tcp://127.0.0.1:8786 (they need feeder_bt and the scenario's files)")
    p.add_argument("--out", metavar="OVERLAY.yaml",
                   help="write the best settings here, for `feeder run SCENARIO --overlay`")
    p.add_argument("--study", metavar="FILE.db", default=DEFAULT_STUDY,
                   help=f"the study's SQLite file; rerunning continues it (default "
                        f"{DEFAULT_STUDY})")
    p.add_argument("--space", choices=SPACES, default="ours",
                   help="what to search: ours (everything), watermarks (only the thesis's "
                        "water-mark adjuster), fixed (one constant belt and incline speed)")
    p.add_argument("--supply", metavar="PLAN.yaml", help="run every trial under this supply "
                   "plan")
    p.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    p.add_argument("--world", metavar="WORLD.yaml",
                   help="tune on this world (a twin from `feeder twin fit`): the simulated "
                        "cell's truth, the controller still on the cell file")
    p.add_argument("--grid", action="store_true",
                   help="with --space fixed: a grid over the two speeds and every pick "
                        "policy within --trials points, instead of TPE")
    p.add_argument("--max-recirc", type=_budget, default=DEFAULT_MAX_RECIRC, metavar="R",
                   help=f"wear budget: a setting may recirculate at most R parts per placed "
                        f"part (the mean of its seeds); those over it are never the best "
                        f"(default {DEFAULT_MAX_RECIRC:g}; 'off' for none)")
    p.add_argument("--halving", action=argparse.BooleanOptionalAction, default=True,
                   help="short trials first: a quarter run on seed 1, then the whole run, "
                        "then the other seeds, each rung keeping the best 1/--eta of the "
                        "trials (default on; --no-halving runs every trial whole)")
    p.add_argument("--eta", type=positive_int, default=3,
                   help="with halving: each rung keeps the best 1/ETA (default 3)")
    p.add_argument("--minutes", type=positive, default=None,
                   help="wall-clock budget of the whole command: no run starts that would "
                        "end after it (5 s kept for the start and the wrap-up); trials cut "
                        "short are pruned (with --trials as the most to try)")
    p.add_argument("--sampler-seed", type=int, default=0,
                   help="seed of the search itself (default 0)")
    p.set_defaults(handler=cmd_tune)
    return p


def _budget(text: str) -> float | None:
    """``--max-recirc``: a number >= 0, or off/none for no wear budget."""
    if text.strip().lower() in ("off", "none"):
        return None
    return non_negative(text)


def _executor(args: argparse.Namespace, stack: ExitStack) -> tuple[cf.Executor, int, str]:
    """The executor the trials run on, how many runs to keep in flight, and its name."""
    if args.dask:
        if args.workers:
            raise TuneUsage("--workers is for local processes; a Dask cluster has its own")
        try:
            from distributed import Client
        except ImportError:
            raise TuneUsage("--dask needs dask.distributed: pip install 'dask[distributed]'"
                            ) from None
        try:
            client = stack.enter_context(Client(args.dask, timeout=10))
        except (OSError, TimeoutError, ValueError) as e:
            raise TuneUsage(f"--dask {args.dask}: cannot reach the scheduler ({e})") from None
        # one run at a time per worker process (the trees' blackboard is per process)
        workers = len(client.scheduler_info().get("workers", {})) or 1
        return client.get_executor(pure=False), workers, f"Dask {args.dask}, {workers} workers"
    workers = args.workers or os.cpu_count() or 1
    if workers == 1:
        from feeder_bt.tuning.search import InlineExecutor
        return InlineExecutor(), 1, "this process"
    ctx = multiprocessing.get_context("forkserver")
    pool = stack.enter_context(cf.ProcessPoolExecutor(workers, mp_context=ctx))
    return pool, workers, f"{workers} local processes"


def cmd_tune(args: argparse.Namespace) -> int:
    started = time.monotonic()          # --minutes bounds the whole command, from here
    from feeder_bt.tuning.progress import TrialProgress
    from feeder_bt.tuning.search import TuneConfig, best_overlay, describe, run_search, unit_of
    cfg = TuneConfig(scenario=args.scenario, trials=args.trials, duration=args.duration,
                     seeds=args.seeds, space=args.space, study=args.study, cell=args.cell,
                     supply=args.supply, world=args.world, sampler_seed=args.sampler_seed,
                     max_recirc=args.max_recirc, grid=args.grid, halving=args.halving,
                     eta=args.eta, minutes=args.minutes, started=started)
    if args.world:                  # a bad world file: one line now, not every trial failed
        from feeder_bt.config import load_scenario
        from feeder_bt.config.world import load_world
        load_world(args.world, load_scenario(args.scenario, args.cell)[1])
    wall0 = time.monotonic()
    with ExitStack() as stack:
        executor, capacity, where = _executor(args, stack)
        progress = stack.enter_context(TrialProgress(where))
        study = run_search(cfg, executor, capacity, on_start=progress.start,
                           on_trial=progress.trial)
    overlay, best = best_overlay(study, args.max_recirc)
    per_seed = ", ".join(f"{v:.2f}" for v in best.user_attrs.get("per_seed_ppm", []))
    recirc = best.user_attrs.get("recirc_per_placed")
    wear = f", recirculated {recirc:.2f} per placed" if recirc is not None else ""
    unit = unit_of(study)
    print(f"best: trial {best.number}, {best.value:.2f} {unit} (seeds {per_seed}{wear}): "
          f"{describe(overlay)}")
    states = Counter(t.state.name.lower() for t in study.trials)
    how = ", ".join(f"{n} {k}" for k, n in sorted(states.items()))
    print(f"study: {args.study} ({study.study_name}, {len(study.trials)} trials: {how}; "
          f"{time.monotonic() - wall0:.0f} s wall)")
    if args.out:
        from feeder_bt.config.overlay import write_overlay
        header = (f"feeder tune {args.scenario}: best of study {study.study_name!r} in "
                  f"{args.study}\ntrial {best.number}: {best.value:.2f} {unit}, the mean "
                  f"of seeds 1-{args.seeds} ({per_seed}), {args.duration:g} s each"
                  + (f", supply plan {args.supply}" if args.supply else "")
                  + f"\nuse: feeder run {args.scenario} --overlay {args.out}")
        write_overlay(args.out, overlay, header)
        print(f"overlay: {args.out}")
    return 0


def main() -> None:  # pragma: no cover - `python -m feeder_bt.cli.tune` for debugging
    from feeder_bt.cli.main import main as cli_main
    sys.exit(cli_main(["tune", *sys.argv[1:]]))
