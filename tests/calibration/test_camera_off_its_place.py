"""The end-to-end check: a simulated camera that is not where the cell file says
misses parts; `feeder calibrate camera` recovers it from pixels; feeding with the written
calibration file is as good as with a perfectly calibrated cell."""

from __future__ import annotations

from pathlib import Path

import yaml

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
TRUTH = {"origin_mm": [83.0, -17.0], "mm_per_px": 1.015, "rotation_deg": 0.4}


def feed(cell: Path | None) -> dict:
    return run_job(RunOptions(scenario=str(ROOT / "scenarios" / "lenses.yaml"),
                              cell=str(cell) if cell else None, duration=300.0, fast=True,
                              seed=2, view="none"))


def test_calibrated_camera_feeds_like_a_perfect_one(tmp_path, capsys):
    doc = yaml.safe_load((ROOT / "cells" / "sim.yaml").read_text())
    doc["camera"]["sim_truth"] = TRUTH
    off = tmp_path / "off.yaml"
    off.write_text(yaml.safe_dump(doc))

    assert main(["calibrate", "camera", str(off), "--write", str(tmp_path / "cam.yaml")]) == 0
    out = capsys.readouterr().out
    assert "rms" in out
    fitted = yaml.safe_load((tmp_path / "cam.yaml").read_text())
    assert fitted["residual_mm"]["max"] < 0.5
    assert abs(fitted["mm_per_px"] - TRUTH["mm_per_px"]) < 0.002

    doc["camera"]["calibration_file"] = "cam.yaml"
    fixed = tmp_path / "fixed.yaml"
    fixed.write_text(yaml.safe_dump(doc))

    perfect, uncalibrated, calibrated = feed(None), feed(off), feed(fixed)
    ref = perfect["parts_per_minute"]
    assert uncalibrated["parts"]["missed"] > 10 * max(1, calibrated["parts"]["missed"])
    assert uncalibrated["parts_per_minute"] < 0.8 * ref
    assert abs(calibrated["parts_per_minute"] - ref) <= 0.05 * ref
    assert calibrated["parts"]["lost"] == 0
