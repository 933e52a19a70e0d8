"""How good a setting ``feeder tune`` reaches in a fixed wall time, against the grid-best
fixed setting, both under the same wear budget and judged on fresh seeds.

    python benchmarks/tune_bench.py [--minutes 10] [--workers 2] [--sampler-seeds 0 1 2]
        [--eval-seeds 5] [--eval-duration 600] [--max-recirc 1.5] [--out PATH]

For each sampler seed, ``feeder tune scenarios/lenses.yaml --minutes M --workers W
--max-recirc R`` runs as a user would run it (its defaults otherwise: successive halving,
600 s x 2 seeds at the last rung), in a child process, timed by the wall clock; its
overlay is then run on the fresh seeds 101.. (never seen while tuning), 600 s each. The
reference is the grid-best fixed setting within the budget of
``benchmarks/results/frontier.json`` (``frontier_bench.py``: 140 fixed settings screened,
the best run on the same fresh seeds), run again here on those seeds with this code.
The goal: the median over the sampler seeds of (tuned fresh-seed mean) / (fixed
fresh-seed mean) >= 0.98, each search within M minutes. Writes JSON
(``benchmarks/results/tune.json``).
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import json
import multiprocessing
import os
import platform
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.tuning.objective import Job, evaluate  # noqa: E402

LENSES = ROOT / "scenarios" / "lenses.yaml"
FRESH_SEED0 = 100
GOAL = 0.98


def fresh(pool: cf.Executor, overlay: dict, args: argparse.Namespace) -> dict:
    """``overlay`` on the fresh seeds: parts/min per seed, mean, recirculations."""
    seeds = range(FRESH_SEED0 + 1, FRESH_SEED0 + args.eval_seeds + 1)
    rows = list(pool.map(evaluate, [Job(str(LENSES), overlay, s, args.eval_duration)
                                    for s in seeds]))
    bad = [r["error"] for r in rows if r.get("error")]
    if bad:
        raise SystemExit(f"tune_bench: a fresh-seed run failed: {bad[0]}")
    ppm = [r["ppm"] for r in rows]
    return {"seeds": list(seeds), "ppm": ppm, "mean": round(statistics.mean(ppm), 3),
            "sd": round(statistics.stdev(ppm), 3) if len(ppm) > 1 else 0.0,
            "recirc_per_placed": round(statistics.mean(r["recirc_per_placed"]
                                                       for r in rows), 3)}


def tune(seed: int, args: argparse.Namespace, tmp: Path) -> dict:
    """One ``feeder tune`` search, as a user runs it; its best and its wall time."""
    study, out = tmp / f"tune{seed}.db", tmp / f"tune{seed}.yaml"
    cmd = [sys.executable, "-m", "feeder_bt.cli", "tune", str(LENSES), "--minutes",
           str(args.minutes), "--trials", str(args.trials), "--workers", str(args.workers),
           "--sampler-seed", str(seed), "--max-recirc", str(args.max_recirc),
           "--study", str(study), "--out", str(out)]
    t0 = time.monotonic()
    done = subprocess.run(cmd, capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(ROOT)})
    wall = time.monotonic() - t0
    if done.returncode != 0:
        raise SystemExit(f"tune_bench: feeder tune failed: {done.stderr.strip()[-400:]}")
    best = next(line for line in done.stdout.splitlines() if line.startswith("best:"))
    summary = next(line for line in done.stdout.splitlines() if line.startswith("study:"))
    value = float(re.search(r", ([0-9.]+) parts/min", best).group(1))
    import yaml
    overlay = yaml.safe_load(out.read_text())
    print(f"sampler seed {seed}: {best} [{summary}] in {wall:.0f} s", file=sys.stderr,
          flush=True)
    return {"sampler_seed": seed, "wall_s": round(wall, 1), "best_line": best,
            "study_line": summary, "tuned_ppm": value, "overlay": overlay}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--trials", type=int, default=100000, help="the most to try")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--sampler-seeds", type=int, nargs="*", default=[0, 1, 2])
    ap.add_argument("--eval-seeds", type=int, default=5)
    ap.add_argument("--eval-duration", type=float, default=600.0)
    ap.add_argument("--max-recirc", type=float, default=1.5)
    ap.add_argument("--frontier", type=Path,
                    default=ROOT / "benchmarks" / "results" / "frontier.json")
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "tune.json")
    args = ap.parse_args(argv)
    frontier = json.loads(args.frontier.read_text())
    if frontier.get("max_recirc") != args.max_recirc:
        raise SystemExit(f"tune_bench: {args.frontier} was screened under max_recirc "
                         f"{frontier.get('max_recirc')}, not {args.max_recirc}")
    ref = frontier["best_fixed"]
    load0 = os.getloadavg()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="tune-bench-") as d:
        searches = [tune(s, args, Path(d)) for s in args.sampler_seeds]
    ctx = multiprocessing.get_context("forkserver")
    with cf.ProcessPoolExecutor(args.workers, mp_context=ctx) as pool:
        fixed = {"setting": ref["setting"], "overlay": ref["overlay"],
                 "frontier_mean": ref["mean"], **fresh(pool, ref["overlay"], args)}
        print(f"grid-best fixed ({ref['setting']}): {fixed['mean']:.2f} parts/min on the "
              f"fresh seeds", file=sys.stderr, flush=True)
        for s in searches:
            s["fresh"] = fresh(pool, s["overlay"], args)
            s["of_fixed"] = round(s["fresh"]["mean"] / fixed["mean"], 4)
            s["within_minutes"] = s["wall_s"] <= 60.0 * args.minutes
            print(f"sampler seed {s['sampler_seed']}: fresh {s['fresh']['mean']:.2f} "
                  f"({100 * s['of_fixed']:.1f} % of the fixed), recirculated "
                  f"{s['fresh']['recirc_per_placed']:.2f} per placed", file=sys.stderr,
                  flush=True)
    ratio = statistics.median(s["of_fixed"] for s in searches)
    result = {"benchmark": "tune", "command": " ".join(["python", "benchmarks/tune_bench.py",
                                                        *(argv or sys.argv[1:])]),
              "scenario": str(LENSES.relative_to(ROOT)), "minutes": args.minutes,
              "workers": args.workers, "max_recirc": args.max_recirc,
              "eval_duration_s": args.eval_duration, "fixed": fixed, "searches": searches,
              "median_of_fixed": ratio, "goal": GOAL, "met": ratio >= GOAL and all(
                  s["within_minutes"] for s in searches),
              "load_average_1_5_15": {"before": [round(x, 2) for x in load0],
                                      "after": [round(x, 2) for x in os.getloadavg()]},
              "wall_s": round(time.monotonic() - t0, 1), "cpus": os.cpu_count(),
              "python": platform.python_version(), "machine": platform.machine()}
    print(f"median of the three: {100 * ratio:.1f} % of the grid-best fixed setting "
          f"(goal {100 * GOAL:.0f} %): {'met' if result['met'] else 'not met'}",
          file=sys.stderr)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
