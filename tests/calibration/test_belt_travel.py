"""The belt's measured direction is used, not thrown away: a robot frame turned from the
belt's travel is named by `feeder calibrate belt` with the `robot.base_deg` that squares
it, and the direction from a marker's moves is exact for any angle."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from feeder_bt.calibration.belt import TRAVEL_LIMIT_DEG, travel_deg
from feeder_bt.calibration.procedure import CalibrationError
from feeder_bt.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("deg", [-2.0, 0.0, 0.7, 30.0])
def test_the_direction_of_a_markers_moves(deg):
    r = math.radians(deg)
    moves = [(d * math.cos(r) + 0.01 * (-1) ** i, d * math.sin(r)) for i, d in
             enumerate((40.0, 80.0, 120.0, 160.0))]
    assert travel_deg(moves) == pytest.approx(deg, abs=0.02)


def test_too_short_a_travel_is_refused():
    with pytest.raises(CalibrationError, match="at least 50 mm"):
        travel_deg([(10.0, 0.0), (20.0, 0.0)])


def test_calibrate_belt_says_the_robot_frame_is_turned_from_the_travel(tmp_path, capsys):
    out = tmp_path / "belt.yaml"
    assert main(["calibrate", "belt", str(ROOT / "cells" / "sim.yaml"), "--sim-frame-deg",
                 "2", "--write", str(out)]) == 0
    text = capsys.readouterr().out
    assert "the belt travels 2.0" in text and f"over {TRAVEL_LIMIT_DEG:g} deg" in text
    assert "Set robot.base_deg: -2.0" in text
    found = yaml.safe_load(out.read_text())
    assert found["travel_in_cell_deg"] == pytest.approx(2.0, abs=0.05)
    assert found["base_deg_square_to_travel"] == pytest.approx(-2.0, abs=0.05)
    assert main(["calibrate", "belt", str(ROOT / "cells" / "sim.yaml")]) == 0
    assert "(within 0.1 deg)" in capsys.readouterr().out
