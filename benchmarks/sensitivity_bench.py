"""The sensitivity table: which of the simulated cell's figures move the thesis
comparison most. One figure changed at a time, from its documented value
(docs/simulator.md) to a plausible other one; each row the mean and spread over seeds.

    python benchmarks/sensitivity_bench.py [--seeds 1 2 3 4 5] [--workers 2]
        [--out benchmarks/results/sensitivity.json]

The new feeder runs scenarios/lenses.yaml as shipped (the thesis's water marks) for 600 s;
the original runs scenarios/original_cwru_lenses.yaml for 1800 s (it is 7x slower, so the
same number of parts needs longer). A variant is a copy of the cell file with one key
changed, written beside the original so its relative paths still hold, and removed after.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import copy
import json
import os
import platform
import statistics
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

FEEDERS = {
    "new": (ROOT / "scenarios/lenses.yaml", ROOT / "cells/sim.yaml", 600.0),
    "original": (ROOT / "scenarios/original_cwru_lenses.yaml",
                 ROOT / "cells/original_cwru.yaml", 1800.0),
}

#: (label, dotted key in the cell file, value); None: the cell as shipped
VARIANTS: list[tuple[str, str | None, Any]] = [
    ("as documented", None, None),
    ("ideal cell (every imperfection off)", "sim.ideal", True),
    ("grip curve twice as wide (1.0 mm)", "sim.grip_width_mm", 1.0),
    ("grip tolerance 3 mm (not 4)", "robot.grip_tolerance_mm", 3.0),
    ("clumping twice as steep with loading (0.4)", "sim.clump_cover_scale", 0.4),
    ("landing slide doubled (4 mm)", "sim.land_slide_mm", 4.0),
    ("calibration residual doubled", "sim.calib_offset_mm", [1.0, -0.8]),
    ("robot time cv 5 % (not 2 %)", "sim.robot_time_cv", 0.05),
    ("hopper release rate -30 %", "hopper.release_per_mm", "x0.7"),
    ("vision latency doubled", "camera.vision_latency_s", "x2"),
    ("robot command overhead halved", "robot.command_overhead_s", "x0.5"),
]


def _set(doc: dict, dotted: str, value: Any) -> None:
    *path, last = dotted.split(".")
    node = doc
    for k in path:
        node = node.setdefault(k, {})
    if isinstance(value, str) and value.startswith("x"):
        value = float(node.get(last, 0.0)) * float(value[1:])
    node[last] = value


def _run(feeder: str, label: str, key: str | None, value: Any, seed: int) -> dict[str, Any]:
    from feeder_bt.app.run import RunOptions, run_job

    scenario, cell, duration = FEEDERS[feeder]
    tmp = None
    if key is not None:
        doc = copy.deepcopy(yaml.safe_load(cell.read_text()))
        _set(doc, key, value)
        tmp = cell.with_name(f".sens-{uuid.uuid4().hex[:8]}-{cell.name}")
        tmp.write_text(yaml.safe_dump(doc, sort_keys=False))
    try:
        r = run_job(RunOptions(scenario=str(scenario), cell=str(tmp) if tmp else None,
                               duration=duration, fast=True, seed=seed, view="none", db=None))
    finally:
        if tmp is not None:
            tmp.unlink(missing_ok=True)
    return {"feeder": feeder, "variant": label, "seed": seed, "ppm": r["parts_per_minute"],
            "missed": r["parts"]["missed"], "lost": r["parts"]["lost"], "state": r["state"]}


def _stats(xs: list[float]) -> dict[str, float]:
    return {"mean": round(statistics.fmean(xs), 2), "min": min(xs), "max": max(xs),
            "sd": round(statistics.stdev(xs), 2) if len(xs) > 1 else 0.0}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/sensitivity.json"))
    a = ap.parse_args(argv)
    t0 = time.time()
    jobs = [(f, label, key, value, s) for f in FEEDERS for label, key, value in VARIANTS
            if not (f == "new" and key == "robot.command_overhead_s")   # 0 on the new cell
            for s in a.seeds]
    with cf.ProcessPoolExecutor(a.workers) as pool:
        runs = list(pool.map(_run, *zip(*jobs, strict=True)))
    rows = []
    for label, _, _ in VARIANTS:
        row: dict[str, Any] = {"variant": label}
        for f in FEEDERS:
            xs = [r["ppm"] for r in runs if r["feeder"] == f and r["variant"] == label]
            row[f] = _stats(xs) if xs else None
        if row["new"] and row["original"]:
            row["ratio"] = round(row["new"]["mean"] / row["original"]["mean"], 2)
        rows.append(row)
    out = {"benchmark": "sensitivity", "seeds": a.seeds, "machine": platform.machine(),
           "command": "python benchmarks/sensitivity_bench.py " + " ".join(argv or sys.argv[1:]),
           "wall_seconds": round(time.time() - t0, 1), "rows": rows, "runs": runs}
    Path(a.out).write_text(json.dumps(out, indent=1))
    print("| change (one at a time) | new feeder, parts/min | original, parts/min | ratio |")
    print("|---|---|---|---|")
    for row in rows:
        def cell(s: dict | None) -> str:
            return "—" if not s else f"{s['mean']:.1f} ({s['min']:.1f}–{s['max']:.1f})"
        print(f"| {row['variant']} | {cell(row['new'])} | {cell(row['original'])} | "
              f"{row.get('ratio', '—')} |")
    return out


if __name__ == "__main__":
    main()
