"""FIFO against lookahead at a fast belt: the picks that fail, same seeds; JSON out.

    python benchmarks/missed_bench.py [--duration 600] [--seeds 1 2 3 4 5] [--out PATH]

Runs scenarios/lenses.yaml with no adjuster, the belt held at 260 mm/s and the incline at
38.46 % of it (the frontier's best fixed setting within the wear budget,
benchmarks/results/frontier.json), once with ``fifo`` and once with ``lookahead``, in
virtual time, and writes benchmarks/results/missed.json: per seed and policy the failed
picks (``misses``: missed grabs, the gripper closed on nothing, and picks refused as out
of reach), the parts dropped as too far before a pick was sent, and parts/min. Every
pick policy prices reach with the same learnt arm model (docs/scenarios.md,
``reach_time_s``), so FIFO's failed picks should be lookahead's, give or take a couple.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402

SCENARIO = "scenarios/lenses.yaml"
BELT_MM_S = 260.0
INCLINE_PCT = 38.46
POLICIES = ("fifo", "lookahead")


def overlay(policy: str) -> str:
    return (f"present: {{horizontal_mm_s: {BELT_MM_S}, incline_pct: {INCLINE_PCT}}}\n"
            f"adjust: {{algorithm: none}}\nretrieve: {{policy: {policy}}}\n")


def one(policy: str, seed: int, duration: float) -> dict:
    """One run: its failed picks by kind, too-far drops and parts/min."""
    with tempfile.TemporaryDirectory(prefix="missed-") as d:
        path = Path(d) / "overlay.yaml"
        path.write_text(overlay(policy))
        r = run_job(RunOptions(scenario=str(ROOT / SCENARIO), duration=duration, fast=True,
                               seed=seed, view="none", overlay=str(path)))
    misses = dict(r.get("misses") or {})
    return {"policy": policy, "seed": seed, "parts_per_minute": r["parts_per_minute"],
            "missed_grab": misses.get("missed_grab", 0),
            "out_of_reach": misses.get("envelope", 0),
            "failed_picks": sum(misses.values()),
            "too_far": r["parts"]["too_far"],
            "lost": r["parts"]["lost"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=600.0)
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "missed.json"))
    a = ap.parse_args(argv)
    runs = []
    for seed in a.seeds:
        for policy in POLICIES:
            runs.append(one(policy, seed, a.duration))
            r = runs[-1]
            print(f"seed {seed} {policy}: {r['parts_per_minute']:.2f} parts/min, failed picks "
                  f"{r['failed_picks']} (missed grab {r['missed_grab']}, out of reach "
                  f"{r['out_of_reach']}), too far {r['too_far']}", flush=True)
    by = {p: [r for r in runs if r["policy"] == p] for p in POLICIES}
    excess = [f["failed_picks"] - k["failed_picks"]
              for f, k in zip(by["fifo"], by["lookahead"], strict=True)]
    out = {"scenario": SCENARIO, "belt_mm_s": BELT_MM_S, "incline_pct": INCLINE_PCT,
           "duration_s": a.duration, "seeds": a.seeds, "runs": runs,
           "mean": {p: {k: round(statistics.mean(r[k] for r in rs), 2)
                        for k in ("parts_per_minute", "failed_picks", "missed_grab",
                                  "out_of_reach", "too_far")} for p, rs in by.items()},
           "fifo_minus_lookahead_failed_picks": excess,
           "command": "python benchmarks/missed_bench.py " + " ".join(argv or sys.argv[1:])}
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=2) + "\n")
    print(f"FIFO's failed picks less lookahead's, seed by seed: {excess} "
          f"(at most {max(excess)})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
