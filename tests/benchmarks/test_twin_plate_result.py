"""benchmarks/twin_bench.py --plate: the committed round trip meets its goal (the twin
within 5 % at the other settings, the cell file's defaults further off) and the docs
quote its figures (`python benchmarks/twin_bench.py --plate` rewrites the JSON)."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULT = json.loads((ROOT / "benchmarks/results/twin_plate.json").read_text())


def test_the_plate_round_trip_meets_its_goal() -> None:
    assert RESULT["plants"] == RESULT["plants_done"] == 3
    assert RESULT["duration_s"] == 600.0
    assert RESULT["scenario"] == "scenarios/plate_lenses.yaml"
    assert len(RESULT["settings"]) == 4                 # the fit's own and three others
    mae = RESULT["other_settings_mae_pct"]
    assert mae["twin_mae_pct"] <= 5.0
    assert mae["defaults_mae_pct"] > mae["twin_mae_pct"]


def test_the_docs_quote_the_committed_figures() -> None:
    mae = RESULT["other_settings_mae_pct"]
    twin, defaults = f"{mae['twin_mae_pct']:.1f} %", f"{mae['defaults_mae_pct']:.1f} %"
    for doc in ("docs/tuning.md", "docs/plate-feeders.md"):
        text = (ROOT / doc).read_text()
        assert "python benchmarks/twin_bench.py --plate" in text, doc
        assert twin in text and defaults in text, (doc, twin, defaults)
    table = (ROOT / "docs/plate-feeders.md").read_text()
    for name, v in RESULT["settings"].items():
        assert f"{v['twin_mae_pct']:.1f} %" in table and name in table, name
