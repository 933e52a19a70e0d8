"""Time whole fast runs of the shipped scenarios and write what they report as JSON.

    python benchmarks/run_bench.py [--duration 3600] [--seeds 1] [--repeats 1] [--out PATH]

Simulator speed (lenses with vision in the loop >= 100x real time)::

    python benchmarks/run_bench.py --scenarios lenses --repeats 5 \\
        --out benchmarks/results/simspeed.json

Each (scenario, seed) runs ``--repeats`` times in a row; a fast run is deterministic, so
the repeats must report the same counts (checked), and only the time differs: the
simulated seconds per wall second are given per repeat and as min / median / max, with
the process CPU time (all threads) and the load average around the runs, since the
project's 2-core machine is shared and one run's speed says little on its own. The
target: lenses, one simulated hour, seed 1: >= 60 parts/min, nothing lost, under 120 s of
wall time. Speed is measured here, never in tests.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402

SCENARIOS = ("lenses", "squares", "lenses_and_squares")


def _counts(r: dict) -> tuple:
    """What must not change between repeats of one (scenario, seed)."""
    p = r["parts"]
    return (json.dumps(p["retrieved"], sort_keys=True), p["located"], p["missed"], p["lost"],
            p["misoriented"], r["vision"]["frames"], r["tick"]["ticks"], r["tick"]["skipped"])


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--seeds", type=int, default=1, help="seeds 1..N per scenario")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each (scenario, seed)")
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "runs.json"))
    args = ap.parse_args(argv)
    rows = []
    load0 = os.getloadavg()
    for name in args.scenarios:
        for seed in range(1, args.seeds + 1):
            speeds, walls, cpus, first = [], [], [], None
            for _ in range(args.repeats):
                c0 = time.process_time()
                r = run_job(RunOptions(scenario=str(ROOT / "scenarios" / f"{name}.yaml"),
                                       duration=args.duration, fast=True, seed=seed,
                                       view="none"))
                cpus.append(round(time.process_time() - c0, 2))
                walls.append(r["wall_seconds"])
                speeds.append(round(r["sim_seconds"] / max(r["wall_seconds"], 1e-9), 1))
                if first is None:
                    first = r
                elif _counts(r) != _counts(first):
                    raise SystemExit(f"{name} seed {seed}: a repeat reported other counts "
                                     f"{_counts(r)} than the first {_counts(first)}")
                print(f"{name} seed {seed}: {r['parts_per_minute']:.1f}/min, lost "
                      f"{r['parts']['lost']}, {r['wall_seconds']:.1f} s wall "
                      f"({speeds[-1]:.0f}x)", file=sys.stderr)
            r = first
            rows.append({"scenario": name, "seed": seed, "sim_seconds": r["sim_seconds"],
                         "wall_seconds": statistics.median(walls), "wall_seconds_runs": walls,
                         "sim_per_wall": statistics.median(speeds),
                         "sim_per_wall_runs": speeds,
                         "sim_per_wall_min_max": [min(speeds), max(speeds)],
                         "cpu_seconds_runs": cpus,
                         "parts_per_minute": r["parts_per_minute"],
                         "retrieved": r["parts"]["retrieved"], "located": r["parts"]["located"],
                         "missed": r["parts"]["missed"], "lost": r["parts"]["lost"],
                         "misoriented": r["parts"]["misoriented"], "tick": r["tick"],
                         "vision": r["vision"]})
    result = {"benchmark": "runs", "duration_s": args.duration, "repeats": args.repeats,
              "runs": rows, "load_average_1_5_15": {"before": [round(x, 2) for x in load0],
                                                     "after": [round(x, 2)
                                                               for x in os.getloadavg()]},
              "cpus": os.cpu_count(), "python": platform.python_version(),
              "machine": platform.machine()}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
