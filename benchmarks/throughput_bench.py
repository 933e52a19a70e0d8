"""Throughput of adjusters x pick policies over seeds, one simulated hour each; JSON out.

    python benchmarks/throughput_bench.py [--duration 3600] [--seeds 5] [--workers 2]
        [--scenarios lenses squares] [--adjusters water_marks supply_queue]
        [--policies fifo lookahead] [--extra none:fifo] [--original] [--out PATH]

Only ``adjust`` and ``retrieve.policy`` differ between the runs of one scenario: the cell,
the vision, the seeds and the simulator are the same. ``--original`` adds the original
CWRU feeder (scenarios/original_cwru_lenses.yaml) as it is. Runs go to a process pool.
"""

from __future__ import annotations

import argparse
import itertools
import json
import platform
import re
import statistics
import sys
import tempfile
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.app.run import RunOptions, run_job  # noqa: E402

#: The adjust section each adjuster is benchmarked with (None: the scenario's own).
ADJUST_SECTIONS: dict[str, str | None] = {
    "scenario": None,
    "none": "adjust:\n  algorithm: none\n",
    "queue_proportional": ("adjust:\n  algorithm: queue_proportional\n  period_s: 0.5\n"),
    "water_marks": ("adjust:\n  algorithm: water_marks\n  period_s: 0.5\n  params: {high: 100, "
                    "low: 50, gain: 0.10, step: 5, min_mm_s: 80, max_mm_s: 200, "
                    "median_mm_s: 150}\n"),
    # within the cell's limits like every other setting: a belt held at 250 mm/s
    # and the incline up to 160 % of it, 400 mm/s, the incline's max_mm_s
    "supply_queue": ("adjust:\n  algorithm: supply_queue\n  period_s: 0.5\n  params: "
                     "{target_queue: 24, horizontal_mm_s: 250, max_incline_pct: 160, "
                     "max_mm_s: 250}\n"),
}


def variant(scenario: Path, adjuster: str, policy: str | None, tmp: Path) -> Path:
    """A copy of ``scenario`` with only its adjust section and pick policy replaced."""
    text = scenario.read_text()
    cell = re.search(r"^cell:\s*(\S+)", text, re.M)
    if cell:
        text = text.replace(cell.group(0), f"cell: {(scenario.parent / cell.group(1)).resolve()}")
    section = ADJUST_SECTIONS[adjuster]
    if section is not None:
        text = re.sub(r"^adjust:\n(?:[ #].*\n|\n)*", section, text + "\n", flags=re.M)
    if policy is not None:
        text = re.sub(r"^(  policy:) *\S+", rf"\1 {policy}", text, flags=re.M)
    out = tmp / f"{scenario.stem}__{adjuster}__{policy or 'own'}.yaml"
    out.write_text(text)
    return out


def _one(job: tuple[str, str, str, str | None, int, float]) -> dict:
    path, name, adjuster, policy, seed, duration = job
    r = run_job(RunOptions(scenario=path, duration=duration, fast=True, seed=seed, view="none"))
    p = r["parts"]
    return {"scenario": name, "adjuster": adjuster, "policy": policy or "scenario", "seed": seed,
            "parts_per_minute": r["parts_per_minute"], "robot_bound_ppm": r["robot_bound_ppm"],
            "located": p["located"], "too_far": p["too_far"], "missed": p["missed"],
            "lost": p["lost"], "landed_touching": r.get("world", {}).get("landed_touching"),
            "sim_seconds": r["sim_seconds"], "wall_seconds": r["wall_seconds"],
            "tick": r["tick"], "vision": r["vision"]}


def summarise(rows: list[dict]) -> list[dict]:
    """Mean, min and max parts/min per (scenario, adjuster, policy)."""
    groups: dict[tuple[str, str, str], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["scenario"], row["adjuster"], row["policy"]), []).append(row)
    out = []
    for (scen, adj, pol), rs in sorted(groups.items()):
        ppm = [r["parts_per_minute"] for r in rs]
        out.append({"scenario": scen, "adjuster": adj, "policy": pol, "seeds": len(rs),
                    "ppm_mean": round(statistics.mean(ppm), 2), "ppm_min": min(ppm),
                    "ppm_max": max(ppm), "robot_bound_ppm": rs[0]["robot_bound_ppm"],
                    "lost": sum(r["lost"] or 0 for r in rs),
                    "sim_per_wall": round(sum(r["sim_seconds"] for r in rs)
                                          / max(sum(r["wall_seconds"] for r in rs), 1e-9), 1)})
    return out


def targets(summary: list[dict]) -> dict[str, dict]:
    """The checks per scenario: the best adjuster + policy against the water-mark
    adjuster with the thesis's FIFO order, and against the robot bound."""
    out: dict[str, dict] = {}
    for scen in sorted({row["scenario"] for row in summary}):
        rows = [r for r in summary if r["scenario"] == scen]
        best = max(rows, key=lambda r: r["ppm_mean"])
        entry = {"best": f"{best['adjuster']} + {best['policy']}",
                 "best_ppm": best["ppm_mean"],
                 "of_robot_bound": round(best["ppm_mean"] / best["robot_bound_ppm"], 3)}
        wm = [r for r in rows if r["adjuster"] == "water_marks" and r["policy"] == "fifo"]
        if wm:
            entry["water_marks_fifo_ppm"] = wm[0]["ppm_mean"]
            entry["vs_water_marks"] = round(best["ppm_mean"] / wm[0]["ppm_mean"], 3)
        out[scen] = entry
    return out


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--seeds", type=int, default=5, help="seeds 1..N")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--scenarios", nargs="*", default=["lenses", "squares"])
    ap.add_argument("--adjusters", nargs="*",
                    default=["none", "queue_proportional", "water_marks", "supply_queue"])
    ap.add_argument("--policies", nargs="*",
                    default=["fifo", "earliest_deadline", "shortest_cycle", "lookahead"])
    ap.add_argument("--extra", nargs="*", default=[], metavar="ADJUSTER:POLICY",
                    help="single pairs added to the grid, e.g. none:fifo")
    ap.add_argument("--original", action="store_true", help="add the original CWRU feeder")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "throughput.json"))
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        jobs = []
        for name in args.scenarios:
            src = ROOT / "scenarios" / f"{name}.yaml"
            pairs = list(itertools.product(args.adjusters, args.policies))
            pairs += [tuple(p.split(":", 1)) for p in args.extra
                      if tuple(p.split(":", 1)) not in pairs]
            for adj, pol in pairs:
                path = str(variant(src, adj, pol, tmp))
                jobs += [(path, name, adj, pol, s, args.duration)
                         for s in range(1, args.seeds + 1)]
        if args.original:
            src = ROOT / "scenarios" / "original_cwru_lenses.yaml"
            jobs += [(str(src), "original_cwru_lenses", "scenario", None, s, args.duration)
                     for s in range(1, args.seeds + 1)]
        with Pool(args.workers) as pool:
            rows = []
            for row in pool.imap_unordered(_one, jobs):
                rows.append(row)
                print(f"{row['scenario']:22} {row['adjuster']:13} {row['policy']:15} "
                      f"seed {row['seed']}: {row['parts_per_minute']:7.2f} parts/min",
                      flush=True)
    rows.sort(key=lambda r: (r["scenario"], r["adjuster"], r["policy"], r["seed"]))
    result = {"machine": platform.platform(), "python": platform.python_version(),
              "duration_s": args.duration, "seeds": args.seeds, "summary": summarise(rows),
              "targets": targets(summarise(rows)),
              "runs": rows}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
