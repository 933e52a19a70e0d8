"""The whole cell through the real drivers against the emulators, which run the shipped V+
programs, with the robot base moved and turned 90 degrees in a copy of the cell file (the
file and the emulated arm's true base agree): every pose goes through the cell frame, so
the cell feeds like the simulated cell with the same file. Real time: a soak run
(``python -m pytest -m soak``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.app.run import RunOptions, run_job

ROOT = Path(__file__).resolve().parents[2]


def moved_cell(tmp_path: Path) -> Path:
    """A copy of scenarios/lenses.yaml whose cell has its robot base at (1400, 330),
    turned 90 degrees."""
    cell = (ROOT / "cells" / "sim.yaml").read_text()
    line = "base_mm: [1370, 305]"
    assert line in cell
    cell = cell.replace(line, "base_mm: [1400, 330]\n  base_deg: 90  #")
    (tmp_path / "cell.yaml").write_text(cell)
    scenario = (ROOT / "scenarios" / "lenses.yaml").read_text()
    assert "cell: ../cells/sim.yaml" in scenario
    path = tmp_path / "lenses.yaml"
    path.write_text(scenario.replace("cell: ../cells/sim.yaml", "cell: cell.yaml"))
    return path


@pytest.mark.soak          # real time: a minute of wall clock through the TCP drivers
def test_moved_and_turned_base_feeds_like_the_simulated_cell(tmp_path):
    opts = dict(scenario=str(moved_cell(tmp_path)), duration=60.0, seed=1, view="none",
                db=None)
    emulated = run_job(RunOptions(hal="emulated", **opts))
    simulated = run_job(RunOptions(hal="sim", fast=True, **opts))
    assert emulated["state"] == "STOPPED" and emulated["parts"]["lost"] == 0
    got, want = emulated["parts_per_minute"], simulated["parts_per_minute"]
    assert want > 20
    assert abs(got - want) <= 0.25 * want, (got, want)


@pytest.mark.soak
def test_a_wrong_frame_does_not_feed_silently(monkeypatch):
    """The arm is truly turned 90 degrees, the cell file says 0: every pick misses (or is
    refused), each is counted, nothing is retrieved, the cell stops with a fault."""
    import feeder_bt.emulators.adept as adept

    real = adept.AdeptEmulator.__init__

    def turned(self, plant, *args, **kw):
        bx, by = plant.cell.robot.base_mm
        kw["true_base"] = (bx, by, plant.cell.robot.base_deg + 90.0)
        real(self, plant, *args, **kw)

    monkeypatch.setattr(adept.AdeptEmulator, "__init__", turned)
    report = run_job(RunOptions(scenario="scenarios/lenses.yaml", hal="emulated",
                                duration=45.0, seed=1, view="none", db=None))
    parts = report["parts"]
    assert sum(parts["retrieved"].values()) == 0 and parts["lost"] == 0
    assert parts["missed"] + parts["unreachable"] >= 3
    assert report["state"] == "FAULT"
