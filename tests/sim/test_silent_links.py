"""The simulated cell's link faults die as cables die on the drivers: a ``silent`` link
(a pulled cable) answers nothing, so the trees learn of it only from the driver's time-out,
never sooner; a ``refused`` one fails each call at once. Either way the cell recovers and
loses nothing; the simulator is not kinder than the drivers."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config import load_cell

ROOT = Path(__file__).resolve().parents[2]
LENSES = str(ROOT / "scenarios" / "lenses.yaml")
CUT_AT_S = 100.0


def _run(tmp_path, device: str, how: str) -> tuple[dict, float]:
    plan = tmp_path / f"{device}-{how}.yaml"
    plan.write_text(f"seed: 1\nscripted:\n  - {{at_s: {CUT_AT_S:g}, kind: comms_lost, "
                    f"device: {device}, outage_s: 4, link: {how}}}\n")
    db = tmp_path / f"{device}-{how}.db"
    report = run_job(RunOptions(scenario=LENSES, duration=300.0, fast=True, seed=1,
                                view="none", db=str(db), faults=str(plan)))
    with sqlite3.connect(db) as conn:
        (t,) = conn.execute("SELECT min(t) FROM events WHERE kind='fault' AND "
                            "json_extract(data, '$.kind')='comms_lost'").fetchone()
        (t0,) = conn.execute("SELECT min(t) FROM events WHERE kind='state' AND "
                             "json_extract(data, '$.new')='RUNNING'").fetchone()
    return report, t - (t0 or 0.0)


@pytest.mark.parametrize("device", ["galil", "adept"])
def test_a_silent_link_is_found_only_by_the_drivers_time_out(tmp_path, device):
    cell = load_cell(ROOT / "cells" / "sim.yaml")
    timeout = getattr(cell, device).timeout_s
    silent, found_silent = _run(tmp_path, device, "silent")
    refused, found_refused = _run(tmp_path, device, "refused")
    for report in (silent, refused):
        assert report["state"] == "STOPPED" and report["parts"]["lost"] == 0
        assert report["recoveries"].get("comms_lost", 0) >= 1
    # the same seed and cut: the silent link is found a whole time-out after the refused
    # one (at its next call); never sooner
    assert found_silent - found_refused >= timeout - 0.3, (found_silent, found_refused)
