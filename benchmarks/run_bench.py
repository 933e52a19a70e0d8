"""Time whole fast runs of the shipped scenarios and write what they report as JSON.

    python benchmarks/run_bench.py [--duration 3600] [--seeds 1] [--out PATH]

Issue 2's target: lenses, one simulated hour, seed 1: >= 60 parts/min, nothing lost, under
120 s of wall time on the project's 2-core machine. Speed is measured here, never in tests.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.run import RunOptions, run_job  # noqa: E402

SCENARIOS = ("lenses", "squares", "lenses_and_squares")


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--seeds", type=int, default=1, help="seeds 1..N per scenario")
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "runs.json"))
    args = ap.parse_args(argv)
    rows = []
    for name in args.scenarios:
        for seed in range(1, args.seeds + 1):
            r = run_job(RunOptions(scenario=str(ROOT / "scenarios" / f"{name}.yaml"),
                                   duration=args.duration, fast=True, seed=seed, view="none"))
            rows.append({"scenario": name, "seed": seed, "sim_seconds": r["sim_seconds"],
                         "wall_seconds": r["wall_seconds"],
                         "sim_per_wall": round(r["sim_seconds"] / max(r["wall_seconds"], 1e-9), 1),
                         "parts_per_minute": r["parts_per_minute"],
                         "retrieved": r["parts"]["retrieved"], "lost": r["parts"]["lost"],
                         "misoriented": r["parts"]["misoriented"], "tick": r["tick"],
                         "vision": r["vision"]})
            print(f"{name} seed {seed}: {r['parts_per_minute']:.1f}/min, lost "
                  f"{r['parts']['lost']}, {r['wall_seconds']:.1f} s wall", file=sys.stderr)
    result = {"benchmark": "runs", "duration_s": args.duration, "runs": rows,
              "python": platform.python_version(), "machine": platform.machine()}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
