"""A plate run's summary says what the plate did, and nothing of recirculation: a plate
flips, feeds and dispenses; nothing goes round a return conveyor."""

from __future__ import annotations

from pathlib import Path

from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job

ROOT = Path(__file__).resolve().parents[2]


def test_a_plate_runs_summary_names_its_actions_not_recirculation():
    report = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "plate_lenses.yaml"),
                                duration=120.0, fast=True, seed=1, view="none"))
    text = summary(report)
    assert "recirculated" not in text
    line = next(x for x in text.splitlines() if x.strip().startswith("plate:"))
    assert f"flip {report['plate']['flip']}" in line
    assert f"({report['plate']['decisions']} decisions)" in line
    lenses = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "lenses.yaml"),
                                duration=120.0, fast=True, seed=1, view="none"))
    assert "recirculated" in summary(lenses) and "plate:" not in summary(lenses)
