"""docs/plate-feeders.md's smart-against-fixed table is benchmarks/results/plate.json's
(`python benchmarks/plate_bench.py --duration 1800 --workers 2` rewrites it): the fixed
baseline searched over its period and repetitions, the best kept, and the ratio against
that best."""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _result() -> dict:
    return json.loads((ROOT / "benchmarks/results/plate.json").read_text())


def test_the_fixed_baseline_was_searched_over_periods_and_repetitions():
    d = _result()
    got = {(g["fixed_every"], g["dispense_reps"], g["feed_reps"]) for g in d["fixed_grid"]}
    assert got == {(n, r, f) for n in range(1, 6) for r in (1, 2) for f in (1, 3)}
    best = max(d["fixed_grid"], key=lambda g: g["mean_ppm"])
    assert d["fixed"]["mean_ppm"] == best["mean_ppm"]
    assert d["ratio"] == round(d["smart"]["mean_ppm"] / best["mean_ppm"], 3)
    assert d["duration_s"] == 1800.0 and d["seeds"] == [1, 2, 3, 4, 5]


def test_the_docs_quote_the_committed_plate_bench():
    d = _result()
    text = (ROOT / "docs/plate-feeders.md").read_text()
    smart = re.search(r"^\| smart \| \*\*([\d.]+) ± ([\d.]+)\*\* \| ([\d.]+) % \| (\d+) \|$",
                      text, flags=re.M)
    assert smart
    s = d["smart"]
    assert tuple(map(float, smart.groups())) == (s["mean_ppm"], s["spread_ppm"],
                                                 s["robot_busy_pct"], s["lost"])
    rows = re.findall(r"^\| fixed, every (\d), dispense x(\d), feed x(\d)[^|]* \| ([\d.]+) ± "
                      r"([\d.]+) \| ([\d.]+) % \| (\d+) \|$", text, flags=re.M)
    quoted = sorted(tuple(map(float, r)) for r in rows)
    want = sorted((g["fixed_every"], g["dispense_reps"], g["feed_reps"], g["mean_ppm"],
                   g["spread_ppm"], g["robot_busy_pct"], g["lost"]) for g in d["fixed_grid"])
    assert quoted == want
    flat = " ".join(text.split())
    m = re.search(r"Ratio \*\*([\d.]+)\*\* against the best fixed cycle", flat)
    assert m and float(m.group(1)) == round(d["ratio"], 2)
    assert "Ratio **1.36**" not in flat
