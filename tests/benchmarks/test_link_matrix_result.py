"""benchmarks/link_matrix.py: the fault proxy's matrix. docs/real-cell.md quotes its tables
and its count as the committed JSON has them, and the JSON's verdicts follow its rules."""

from __future__ import annotations

import json
from pathlib import Path

from feeder_bt.app.links import HOWS, LIMIT_S, matrix_table

ROOT = Path(__file__).resolve().parents[2]
RESULT = json.loads((ROOT / "benchmarks/results/link_matrix.json").read_text())


def test_every_verdict_follows_the_rules() -> None:
    for r in RESULT["rows"]:
        e = r["emulated"]
        if e["ok"]:
            assert e["lost"] == 0 and not e["mismatch"], r
            assert e["end"] == "FAULT" or e["placing_after_restore_s"] <= LIMIT_S, r
        assert r["same_verdict"] is (e["end"] == r["simulated"]["end"]), r
    s = RESULT["summary"]
    assert s["runs"] == len(RESULT["rows"])
    assert s["ok"] == sum(r["emulated"]["ok"] for r in RESULT["rows"])
    assert s["same_verdict"] == sum(r["same_verdict"] for r in RESULT["rows"])


def test_the_docs_quote_the_committed_matrix() -> None:
    text = (ROOT / "docs/real-cell.md").read_text()
    for cut_s in sorted({r["cut_s"] for r in RESULT["rows"]}):
        assert matrix_table(RESULT["rows"], cut_s) in text, cut_s
    s = RESULT["summary"]
    assert f"**{s['ok']} of {s['runs']}** runs" in text
    assert f"{s['same_verdict']} of {s['runs']} ended as the simulated cell" in text
    assert "python benchmarks/link_matrix.py" in text


def test_the_camera_row_is_measured_every_way_and_quoted() -> None:
    """The camera's link, killed at the frame source, is a row of the 4 s table like the
    others: all six deaths, each within the rules and as the simulated cell ended."""
    rows = [r for r in RESULT["rows"] if r["link"] == "camera"]
    assert sorted(r["how"] for r in rows if r["cut_s"] == 4.0) == sorted(HOWS)
    for r in rows:
        assert r["emulated"]["ok"] and r["same_verdict"], r
    table = matrix_table(RESULT["rows"], 4.0)
    row = next(line for line in table.splitlines() if line.startswith("| camera |"))
    assert row in (ROOT / "docs/real-cell.md").read_text()
