"""Smart feeding against a fixed cycle on the same plate, same seeds.

    python benchmarks/plate_bench.py [--duration 3600] [--seeds 1 2 3 4 5] [--workers 2]

Runs scenarios/plate_lenses.yaml with its smart feeding and with the fixed cycle of
benchmarks/plate_fixed.yaml (dispense, feed forward and flip on every Nth look that found
nothing new, else flip), in virtual time, and writes benchmarks/results/plate.json:
parts/min per seed, mean and spread (sample standard deviation), robot-busy %, parts lost,
and the ratio of the means. The fixed cycle gets a grid over its period (N = 1..5) by its
repetitions (dispense 1 or 2, feed 1 or 3) on the same seeds, the best kept: a baseline
given the knobs a user would turn.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import itertools
import json
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402

SCENARIO = ROOT / "scenarios" / "plate_lenses.yaml"
FIXED = ROOT / "benchmarks" / "plate_fixed.yaml"


PERIODS = (1, 2, 3, 4, 5)
FIXED_GRID = [{"fixed_every": n, "dispense_reps": d, "feed_reps": f}
              for n, d, f in itertools.product(PERIODS, (1, 2), (1, 3))]


def describe(g: dict) -> str:
    return (f"every {g['fixed_every']}, dispense x{g['dispense_reps']}, "
            f"feed x{g['feed_reps']}")


def fixed_overlay(folder: Path, reps: dict) -> Path:
    """benchmarks/plate_fixed.yaml with these repetitions."""
    import yaml
    overlay = yaml.safe_load(FIXED.read_text())
    overlay["present"]["plate"].update(reps)
    path = folder / (f"fixed_n{reps['fixed_every']}_d{reps['dispense_reps']}"
                     f"_f{reps['feed_reps']}.yaml")
    path.write_text(yaml.safe_dump(overlay))
    return path


def one(seed: int, duration: float, overlay: Path | None) -> dict:
    """One run in virtual time (a run's figures do not depend on the process it ran in)."""
    r = run_job(RunOptions(scenario=str(SCENARIO), duration=duration, fast=True, seed=seed,
                           view="none", overlay=str(overlay) if overlay else None))
    return {"seed": seed, "parts_per_minute": r["parts_per_minute"],
            "robot_busy_pct": r["robot_busy_pct"], "lost": r["parts"]["lost"],
            "state": r["state"], "retrieved": sum(r["parts"]["retrieved"].values())}


def summary(rows: list[dict]) -> dict:
    ppm = [r["parts_per_minute"] for r in rows]
    return {"runs": rows, "mean_ppm": round(statistics.mean(ppm), 2),
            "spread_ppm": round(statistics.stdev(ppm), 2) if len(ppm) > 1 else 0.0,
            "robot_busy_pct": round(statistics.mean(r["robot_busy_pct"] for r in rows), 1),
            "lost": sum(r["lost"] for r in rows)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--periods", type=int, nargs="+", default=list(PERIODS))
    ap.add_argument("--workers", type=int, default=1, help="runs at once (processes)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "plate.json"))
    a = ap.parse_args(argv)
    grid = []
    settings = [reps for reps in FIXED_GRID if reps["fixed_every"] in a.periods]
    with tempfile.TemporaryDirectory() as tmp, \
            cf.ProcessPoolExecutor(max_workers=max(a.workers, 1)) as pool:
        overlays = [fixed_overlay(Path(tmp), reps) for reps in settings]
        smart_jobs = [pool.submit(one, s, a.duration, None) for s in a.seeds]
        jobs = [[pool.submit(one, s, a.duration, ov) for s in a.seeds] for ov in overlays]
        smart = summary([j.result() for j in smart_jobs])
        for reps, js in zip(settings, jobs, strict=True):
            got = summary([j.result() for j in js])
            grid.append({**reps, **got})
            print(f"fixed, {describe(reps)}: {got['mean_ppm']} parts/min", flush=True)
    fixed = max(grid, key=lambda g: g["mean_ppm"])
    out = {"scenario": "scenarios/plate_lenses.yaml", "duration_s": a.duration,
           "seeds": a.seeds, "smart": smart, "fixed": fixed,
           "fixed_grid": [{k: v for k, v in g.items() if k != "runs"} for g in grid],
           "ratio": round(smart["mean_ppm"] / fixed["mean_ppm"], 3) if fixed["mean_ppm"]
           else None,
           "command": "python benchmarks/plate_bench.py " + " ".join(argv or sys.argv[1:])}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=2) + "\n")
    print(f"smart {smart['mean_ppm']} ± {smart['spread_ppm']} parts/min "
          f"(robot busy {smart['robot_busy_pct']} %), best fixed ({describe(fixed)}) "
          f"{fixed['mean_ppm']} ± "
          f"{fixed['spread_ppm']} (robot busy {fixed['robot_busy_pct']} %): "
          f"ratio {out['ratio']}, lost {smart['lost'] + fixed['lost']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
