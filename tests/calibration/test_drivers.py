"""Belt and tool calibration through the Galil and V+ drivers, against the emulators:
the same procedures as on the simulated cell, the belt moved by the Galil
driver, the pose and belt count read from the V+ position server. Real time (~20 s)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from feeder_bt.calibration.drivers import OperatorTouch, real_waiter
from feeder_bt.calibration.procedure import CalibrationError
from feeder_bt.cli import calibrate
from feeder_bt.cli.main import main
from feeder_bt.config import load_cell

ROOT = Path(__file__).resolve().parents[2]
# the simulated cell with generous controller time-outs (cell settings): a reply on a loaded
# machine may be slow, and these tests judge the calibration, not the machine's speed
GENEROUS = """
galil: {timeout_s: 10.0, watchdog_s: 10.0, heartbeat_s: 10.0}
adept: {timeout_s: 10.0, motion_timeout_s: 30.0}
"""


@pytest.fixture(scope="module")
def sim_cell(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("cell") / "sim.yaml"
    path.write_text((ROOT / "cells" / "sim.yaml").read_text() + GENEROUS)
    return path


@pytest.fixture(scope="module")
def cell(sim_cell):
    got = load_cell(sim_cell)
    assert got.galil.timeout_s == 10.0 and got.adept.timeout_s == 10.0
    return got


def test_belt_through_the_emulators(capsys, sim_cell):
    capsys.readouterr()
    assert main(["calibrate", "belt", str(sim_cell), "--hal", "emulated"]) == 0
    out = capsys.readouterr().out
    cpm = float(out.split("counts_per_mm ")[1].split(",")[0])
    assert cpm == pytest.approx(20.0, rel=0.005)
    assert float(out.split("rms ")[1].split()[0]) < 0.3


def test_tool_through_the_emulators(cell):
    fit = calibrate.driver_tool(cell, "emulated", (12.0, -5.0), seed=4, noise_mm=0.05)
    assert math.dist(fit.offset_mm, (12.0, -5.0)) < 0.2
    assert fit.rms_mm < 0.3


def test_operator_at_the_terminal_on_the_emulated_cell(cell, monkeypatch):
    """The real cell's path: the operator jogs the robot (here: the emulated plant's robot,
    moved directly, as a pendant would) and presses Enter; the procedure reads the pose
    through the V+ driver afresh."""
    seen = {}
    real_hal = calibrate._driver_hal

    def capture(*args):
        seen["hal"] = real_hal(*args)
        return seen["hal"]

    monkeypatch.setattr(calibrate, "_driver_hal", capture)
    marker: dict[str, float] = {}

    def pendant(prompt: str) -> str:
        plant = seen["hal"].extras["plant"]
        with plant.lock:
            world = plant.world
            belt = world.horizontal.pos(world.now())
            if not marker:
                marker.update(x=800.0, y=305.0, p0=belt)
            x = marker["x"] + belt - marker["p0"]
        # the person jogs the tool onto the marker (the V+ emulator's pendant)
        seen["hal"].extras["adept_emulator"].pendant_to_cell(x, marker["y"])
        return ""

    fit = calibrate.driver_belt(cell, "emulated", seed=2, ask=pendant, operator=True)
    assert fit.counts_per_mm == pytest.approx(20.0, rel=0.005)
    assert fit.rms_mm < 0.1


def test_operator_touch_ends_on_enter_and_fails_without_a_terminal():
    wait = real_waiter(timeout_s=60.0)                  # bounds a hung test only
    assert wait(OperatorTouch("go ", lambda prompt: "")) is None

    def closed(prompt: str) -> str:
        raise EOFError

    with pytest.raises(CalibrationError, match="no operator"):
        wait(OperatorTouch("go ", closed))


def test_waiter_gives_up_with_one_line():
    from feeder_bt.core.jobs import Job
    with pytest.raises(CalibrationError, match="did not finish within 0.05 s"):
        real_waiter(timeout_s=0.05)(Job("never"))
