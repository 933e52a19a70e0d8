"""Smart feeding against a fixed cycle on the same plate, same seeds (issue 31).

    python benchmarks/plate_bench.py [--duration 3600] [--seeds 1 2 3 4 5]

Runs scenarios/plate_lenses.yaml with its smart feeding and with the fixed cycle of
benchmarks/plate_fixed.yaml (dispense, feed forward, flip after every look that found
nothing new), in virtual time, and writes benchmarks/results/plate.json: parts/min per
seed, mean and spread (sample standard deviation), robot-busy %, parts lost, and the
ratio of the means.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.run import RunOptions, run_job  # noqa: E402

SCENARIO = ROOT / "scenarios" / "plate_lenses.yaml"
FIXED = ROOT / "benchmarks" / "plate_fixed.yaml"


def one(seed: int, duration: float, overlay: Path | None) -> dict:
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
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "plate.json"))
    a = ap.parse_args(argv)
    smart = summary([one(s, a.duration, None) for s in a.seeds])
    fixed = summary([one(s, a.duration, FIXED) for s in a.seeds])
    out = {"scenario": "scenarios/plate_lenses.yaml", "duration_s": a.duration,
           "seeds": a.seeds, "smart": smart, "fixed": fixed,
           "ratio": round(smart["mean_ppm"] / fixed["mean_ppm"], 3) if fixed["mean_ppm"]
           else None,
           "command": "python benchmarks/plate_bench.py " + " ".join(argv or sys.argv[1:])}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=2) + "\n")
    print(f"smart {smart['mean_ppm']} ± {smart['spread_ppm']} parts/min "
          f"(robot busy {smart['robot_busy_pct']} %), fixed {fixed['mean_ppm']} ± "
          f"{fixed['spread_ppm']} (robot busy {fixed['robot_busy_pct']} %): "
          f"ratio {out['ratio']}, lost {smart['lost'] + fixed['lost']}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
