"""Tick time of the four trees (present, locate, retrieve, adjust ticked together), every
tick at the scenario's rate (no idle ticks skipped), p50/p99/max and overruns; JSON out.

    python benchmarks/tick_bench.py [--duration 300] [--out PATH]

Besides each shipped scenario as it is, ``lenses+best`` is lenses with the throughput
benchmark's best pair (``supply_queue`` + ``lookahead``): the most parts on the belt and
the costliest choice of the next part.

The world is simulated on virtual time, so the wall time of a tick is the controller's own
cost (the recipe runs on the vision worker and is not in it). Measured here, never in tests.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from throughput_bench import variant  # noqa: E402

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402

SCENARIOS = ("lenses", "lenses+best", "squares", "lenses_and_squares", "original_cwru_lenses")


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=300.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "ticks.json"))
    args = ap.parse_args(argv)
    rows = []
    tmp = Path(tempfile.mkdtemp())
    for name in args.scenarios:
        path = ROOT / "scenarios" / f"{name.split('+')[0]}.yaml"
        if name.endswith("+best"):
            path = variant(path, "supply_queue", "lookahead", tmp)
        r = run_job(RunOptions(scenario=str(path),
                               duration=args.duration, fast=True, seed=args.seed, view="none",
                               skip_idle=False))
        t = r["tick"]
        rows.append({"scenario": name, "tick_hz": t["hz"], "ticks": t["ticks"],
                     "budget_ms": round(1000.0 / t["hz"], 3), "p50_ms": t["p50_ms"],
                     "p99_ms": t["p99_ms"], "max_ms": t["max_ms"], "overruns": t["overruns"],
                     "sim_seconds": r["sim_seconds"], "wall_seconds": r["wall_seconds"]})
        print(json.dumps(rows[-1]), flush=True)
    result = {"machine": platform.platform(), "python": platform.python_version(),
              "duration_s": args.duration, "runs": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
