"""benchmarks/twin_bench.py: the committed belt round trip meets its goal (the twin within
5 % at the five other settings, the cell file's defaults further off) and docs/simulator.md
quotes its table (`python benchmarks/twin_bench.py` rewrites the JSON)."""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULT = json.loads((ROOT / "benchmarks/results/twin.json").read_text())


def test_the_belt_round_trip_meets_its_goal() -> None:
    assert RESULT["plants"] == RESULT["plants_done"] == 5
    assert RESULT["duration_s"] == 600.0 and RESULT["scenario"] == "scenarios/lenses.yaml"
    assert len(RESULT["settings"]) == 6                 # the fit's own and five others
    mae = RESULT["other_settings_mae_pct"]
    assert mae["twin_mae_pct"] <= 5.0
    assert mae["defaults_mae_pct"] > mae["twin_mae_pct"]


def test_the_docs_quote_the_committed_table() -> None:
    text = (ROOT / "docs/simulator.md").read_text()
    table = text[text.index("| setting | twin: mean abs. error |"):].split("\n\n")[0]
    rows = re.findall(r"^\| (.+?) \| \**([\d.]+) %\** \| \**([\d.]+) %\** \|$", table,
                      flags=re.M)
    want = [(f"{v['twin_mae_pct']:.1f}", f"{v['defaults_mae_pct']:.1f}")
            for v in RESULT["settings"].values()]
    mae = RESULT["other_settings_mae_pct"]
    want.append((f"{mae['twin_mae_pct']:.1f}", f"{mae['defaults_mae_pct']:.1f}"))
    assert [(t, d) for _, t, d in rows] == want
