"""The belt window at commissioning: a cell file whose window the arm cannot reach is
refused before anything connects, and the window the person teaches with the tool is
checked against the reach before it is sent to the controller."""

from __future__ import annotations

import io
from pathlib import Path

from feeder_bt.cli.commission.adept import _window
from feeder_bt.cli.commission.frame import FrameFit
from feeder_bt.cli.commission.steps import Asker
from feeder_bt.cli.main import main
from feeder_bt.config import load_cell

ROOT = Path(__file__).resolve().parents[2]


def test_a_cell_file_window_outside_the_reach_is_refused_in_one_line(tmp_path, capsys):
    text = (ROOT / "cells" / "sim.yaml").read_text()
    text = text.replace("  grip_tolerance_mm: 4.0", "  grip_tolerance_mm: 4.0\n"
                        "  belt_window_mm: [700, 1150]")
    cell = tmp_path / "cell.yaml"
    cell.write_text(text)
    code = main(["commission", "adept", str(cell), "--report", str(tmp_path / "r.json")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "Traceback" not in err, err
    assert len(err.splitlines()) == 1, err
    assert "robot.belt_window_mm" in err and "upstream limit 700 mm is outside" in err


class _Client:
    def __init__(self, here: list[tuple[float, float]]) -> None:
        self.here, self.sent = list(here), []

    def call(self, verb: str, *args):
        if verb == "HERE":
            x, y = self.here.pop(0)
            return [x, y, 0.0, 0.0]
        self.sent.append((verb, *args))
        return []


class _Adept:
    def __init__(self, touches_cell: list[tuple[float, float]], base=(1370.0, 305.0)) -> None:
        # HERE answers in the robot's own world frame: the base at the origin
        self.motion = _Client([])
        self.clients = {"position": _Client([(x - base[0], y - base[1])
                                             for x, y in touches_cell]),
                        "motion": self.motion}


FIT = FrameFit(base_mm=(1370.0, 305.0), base_deg=0.0, rms_mm=0.1, max_mm=0.1)


def _teach(touches):
    cell = load_cell(ROOT / "cells" / "sim.yaml")
    adept = _Adept(touches)
    out = io.StringIO()
    found = _window(cell, adept, Asker({"window.up": "", "window.down": "",
                                        "window.pick": ""}, io.StringIO(), out), FIT)
    return found, adept.motion.sent, out.getvalue()


def test_a_taught_window_inside_the_reach_is_sent_with_its_cell_file_lines():
    found, sent, prompts = _teach([(800.0, 305.0), (1200.0, 305.0), (1140.0, 200.0)])
    assert "upstream limit" in prompts and "x 770.0" in prompts      # the cell file's
    assert found["ok"] and found["taught_mm"] == [800.0, 1200.0, 1140.0]
    assert found["change_mm"] == [30.0, -19.0, -79.0]
    assert sent == [("WINDOW", 800.0, 1200.0, 1140.0)]
    assert found["cell_file_lines"] == ["robot.belt_window_mm: [800, 1200]",
                                        "robot.pick_limit_mm: 1140"]


def test_a_downstream_limit_touched_past_the_belts_end_is_refused_and_not_sent():
    found, sent, _ = _teach([(800.0, 305.0), (1300.0, 305.0), (1140.0, 305.0)])
    assert not found["ok"] and sent == []
    assert "downstream limit 1300 mm is outside the arm's reach over the belt" in found["error"]


def test_limits_out_of_order_are_refused():
    found, sent, _ = _teach([(1100.0, 305.0), (900.0, 305.0), (1000.0, 305.0)])
    assert not found["ok"] and sent == [] and "upstream < pick limit <= downstream" in found["error"]
