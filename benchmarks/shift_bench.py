"""The eight-hour fault shift of docs/faults.md, with and without its faults; JSON out.

    python benchmarks/shift_bench.py [--seeds 1 2 3 4 5] [--duration 28800] [--workers 2]
        [--plan faults/shift.yaml] [--scenario scenarios/lenses.yaml] [--out PATH]

Each seed runs twice on the simulated cell, exactly as a user would with
``feeder run SCENARIO --fast --duration 28800 --seed N --faults PLAN``: once with the plan,
once without. The JSON has, per run, the end state and exit code ``feeder run`` would
give, parts/min, the accounting (lost, duplicated, misplaced), and injected faults
against the cell's faults and recoveries; per seed, the ratio of parts/min with faults to
without; and a ``verdict`` against the bar (STOPPED after the whole shift, exit 0,
nothing lost or duplicated, every injected fault recovered or reported, ≥ 90 % of the
fault-free parts/min). docs/faults.md quotes it.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402
from feeder_bt.config.faults import ERROR_KINDS  # noqa: E402

BAR_RATIO = 0.90


def exit_code(report: dict) -> int:
    """What ``feeder run`` exits with for this report (feeder_bt/cli/main.py)."""
    if report["parts"].get("accounting"):
        return 4
    return 3 if report["fault"] else 0


#: kinds of which each injection fails one call: a second one striking the retry of the
#: first is reported as an attempt of the same episode (``retried``), not a new fault; a
#: dropped link fails many calls in one outage, so its attempts are not injections
ONE_CALL_KINDS = ("servo_timeout", "grab_failed", "missed_grab")


def unrecovered(report: dict) -> dict[str, int]:
    """Injected faults, by kind, that the cell neither recovered nor reported (as a
    retry of the same episode, or as its FAULT). A fault nobody met cannot be recovered
    and is not counted against the run."""
    out = {}
    unseen = report.get("unseen", {})
    for kind, n in report.get("injected", {}).items():
        k = ERROR_KINDS[kind]
        missing = n - unseen.get(kind, 0) - report["recoveries"].get(k, 0)
        if kind in ONE_CALL_KINDS:
            missing -= report.get("retried", {}).get(k, 0)
        if report["fault"] and missing > 0:
            missing -= 1                       # the one that ended the run, reported
        if missing > 0:
            out[kind] = missing
    return out


def _one(job: tuple[str, str | None, int, float]) -> dict:
    scenario, plan, seed, duration = job
    r = run_job(RunOptions(scenario=scenario, duration=duration, fast=True, seed=seed,
                           faults=plan, db=None, view="none"))
    p = r["parts"]
    return {"seed": seed, "faults": plan is not None, "state": r["state"],
            "fault": r["fault"], "exit_code": exit_code(r), "sim_seconds": r["sim_seconds"],
            "parts_per_minute": r["parts_per_minute"],
            "retrieved": sum(p["retrieved"].values()), "lost": p["lost"],
            "duplicated": p["duplicated"], "misplaced": p["misplaced"],
            "accounting": p.get("accounting", []), "injected": r.get("injected", {}),
            "unseen": r.get("unseen", {}), "cell_faults": r["faults"],
            "misses": r.get("misses", {}),            # missed grabs: not faults (vocabulary)
            "recoveries": r["recoveries"], "retried": r.get("retried", {}),
            "unrecovered": unrecovered(r), "watchdog_stops": r.get("watchdog_stops", 0),
            "wall_seconds": r["wall_seconds"]}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--duration", type=float, default=28800.0)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--plan", default=str(ROOT / "faults/shift.yaml"))
    ap.add_argument("--scenario", default=str(ROOT / "scenarios/lenses.yaml"))
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/shift.json"))
    a = ap.parse_args(argv)
    jobs = [(a.scenario, plan, seed, a.duration) for seed in a.seeds
            for plan in (a.plan, None)]
    t0 = time.monotonic()
    with Pool(a.workers) as pool:
        rows = []
        for row in pool.imap_unordered(_one, jobs):
            rows.append(row)
            print(f"seed {row['seed']} {'faults' if row['faults'] else 'clean '}: "
                  f"{row['state']} after {row['sim_seconds']:.0f} s, exit {row['exit_code']}, "
                  f"{row['parts_per_minute']:.2f} parts/min, lost {row['lost']}, "
                  f"duplicated {row['duplicated']}", file=sys.stderr, flush=True)
    rows.sort(key=lambda r: (r["seed"], not r["faults"]))
    seeds = []
    for seed in a.seeds:
        f = next(r for r in rows if r["seed"] == seed and r["faults"])
        c = next(r for r in rows if r["seed"] == seed and not r["faults"])
        ratio = f["parts_per_minute"] / c["parts_per_minute"] if c["parts_per_minute"] else 0.0
        ok = (f["state"] == "STOPPED" and f["exit_code"] == 0
              and f["sim_seconds"] >= a.duration - 1.0 and f["lost"] == 0
              and f["duplicated"] == 0 and not f["unrecovered"] and ratio >= BAR_RATIO)
        seeds.append({"seed": seed, "with_faults_ppm": f["parts_per_minute"],
                      "without_faults_ppm": c["parts_per_minute"], "ratio": round(ratio, 4),
                      "passes": ok})
    ratios = [s["ratio"] for s in seeds]
    out = {
        "benchmark": "shift", "scenario": a.scenario, "plan": a.plan,
        "duration_s": a.duration, "machine": platform.platform(),
        "command": "python benchmarks/shift_bench.py " + " ".join(argv or sys.argv[1:]),
        "wall_seconds": round(time.monotonic() - t0, 1),
        "verdict": {"all_pass": all(s["passes"] for s in seeds),
                    "ratio_mean": round(statistics.mean(ratios), 4),
                    "ratio_min": round(min(ratios), 4), "bar_ratio": BAR_RATIO},
        "seeds": seeds, "runs": rows,
    }
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    Path(a.out).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out["verdict"]), file=sys.stderr)
    return 0 if out["verdict"]["all_pass"] else 1


if __name__ == "__main__":
    sys.exit(main())
