"""World files: the simulated cell's truth, laid over the cell file, never the controller's."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from feeder_bt.app.factory import make_hal
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario
from feeder_bt.config.world import load_world
from feeder_bt.core.errors import ConfigError
from feeder_bt.robot.model import RobotModel
from feeder_bt.robot.scara import world_arm

ROOT = Path(__file__).resolve().parents[2]
LENSES = ROOT / "scenarios/lenses.yaml"


def _world(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "world.yaml"
    p.write_text(text, encoding="utf-8")
    return p


def test_a_world_changes_the_truth_and_leaves_the_beliefs(tmp_path: Path) -> None:
    scenario, cell = load_scenario(LENSES)
    w = load_world(_world(tmp_path, "hopper: {release_per_mm: 0.02}\n"
                                    "conveyors: {return: {transit_s: 9}}\n"
                                    "sim: {arm_j1_deg_s: 300, clump_cover_scale: 0.4}\n"
                                    "fit: {note: anything}\n"), cell)
    assert (w.hopper.release_per_mm, w.return_transit_s) == (0.02, 9.0)
    assert (cell.hopper.release_per_mm, cell.return_transit_s) == (0.030, 12.0)
    assert w.sim.clump_cover_scale == 0.4 and w.sim.clump_prob == cell.sim.clump_prob
    assert w.camera.calibration == cell.camera.calibration
    hal, _ = make_hal("sim", scenario, cell, seed=1, world=w)
    arm = hal.truth.robot_model.scara
    assert math.degrees(arm.j1_rad_s) == pytest.approx(300.0)
    # the joint not given keeps the arm timed to the description
    assert arm.j2_rad_s == pytest.approx(world_arm(cell.robot).scara.j2_rad_s)
    assert hal.truth.cell.hopper.release_per_mm == 0.02


def test_the_world_arm_does_not_follow_a_wrong_description(tmp_path: Path) -> None:
    """A cell file that says the robot is twice as fast does not speed the world's arm up
    when the world states its joints."""
    _, cell = load_scenario(LENSES)
    truth = world_arm(cell.robot)
    import dataclasses
    wrong = dataclasses.replace(cell, robot=dataclasses.replace(
        cell.robot, v_max_mm_s=8000.0, a_max_mm_s2=84000.0))
    from feeder_bt.robot.scara import arm_figures
    text = "sim: {" + ", ".join(f"{k}: {v}" for k, v in arm_figures(truth.scara).items()) + "}\n"
    w = load_world(_world(tmp_path, text), wrong)
    arm = world_arm(w.robot, 1.0, w.sim)
    assert arm.standard_cycle() == pytest.approx(truth.standard_cycle(), rel=1e-9)
    assert RobotModel(wrong.robot).standard_cycle() < 0.6 * arm.standard_cycle()


@pytest.mark.parametrize(("text", "where", "words"), [
    ("sim: {clump_prob: 3}\n", "world.yaml:1: sim.clump_prob", "must be in [0, 1]"),
    ("hoper: {release_per_mm: 1}\n", "world.yaml:1: hoper", "did you mean 'hopper'"),
    ("camera: {calibration_file: c.yaml}\n", "world.yaml:1: camera.calibration_file",
     "controller's belief"),
    ("sim:\n  arm_j2_deg_s: -5\n", "world.yaml:2: sim.arm_j2_deg_s", "must be in"),
])
def test_bad_world_is_one_line_exit_2(tmp_path: Path, capsys, text: str, where: str,
                                      words: str) -> None:
    w = _world(tmp_path, text)
    with pytest.raises(ConfigError):
        load_world(w, load_scenario(LENSES)[1])
    rc = main(["run", str(LENSES), "--fast", "--duration", "5", "--no-db", "--view", "none",
               "--world", str(w)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and where in err[0] and words in err[0] and "Traceback" not in err[0]


def test_an_empty_world_is_the_cell(tmp_path: Path) -> None:
    """Laying nothing over the cell runs the same cell, part for part."""
    w = _world(tmp_path, "sim: {}\n")
    a = run_job(RunOptions(scenario=str(LENSES), duration=60.0, fast=True, seed=2,
                           view="none"))
    b = run_job(RunOptions(scenario=str(LENSES), duration=60.0, fast=True, seed=2,
                           view="none", world=str(w)))
    assert a["parts"]["retrieved"] == b["parts"]["retrieved"]
    assert a["parts"]["located"] == b["parts"]["located"]


def test_the_world_schema_takes_world_figures_only() -> None:
    """`feeder schema world`: an editor checks a world file as the loader does."""
    jsonschema = pytest.importorskip("jsonschema")
    import yaml

    from feeder_bt.config.world import world_schema
    schema = world_schema()
    jsonschema.validate(yaml.safe_load((ROOT / "examples/plant_b.yaml").read_text()), schema)
    for bad in ({"camera": {"calibration_file": "c.yaml"}}, {"name": "x"},
                {"sim": {"clump_prob": 3}}):
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(bad, schema)


def test_the_learnt_robot_model_copes_with_a_wrong_description(tmp_path: Path) -> None:
    """The world's arm 30 % faster than the cell file says: the controller's fitted model
    learns a shorter cycle than its description's; the description is untouched."""
    from feeder_bt.robot.scara import arm_figures
    _, cell = load_scenario(LENSES)
    fast = {k: v * (1.3 if k.endswith("_s") else 1.69)
            for k, v in arm_figures(world_arm(cell.robot).scara).items()}
    w = _world(tmp_path, "sim: {" + ", ".join(f"{k}: {v:.6g}" for k, v in fast.items()) + "}\n")
    base = run_job(RunOptions(scenario=str(LENSES), duration=120.0, fast=True, seed=1,
                              view="none"))["robot_model"]
    quick = run_job(RunOptions(scenario=str(LENSES), duration=120.0, fast=True, seed=1,
                               view="none", world=str(w)))["robot_model"]
    assert quick["nominal"] == base["nominal"]
    assert quick["fitted"]["standard_cycle_s"] < 0.85 * base["fitted"]["standard_cycle_s"]


def test_check_reads_a_world_file_as_one(tmp_path: Path, capsys) -> None:
    """`feeder check` tells a world file by its keys and judges it as any cell file."""
    assert main(["check", str(ROOT / "examples/plant_b.yaml")]) == 0
    assert "a world file" in capsys.readouterr().out
    bad = _world(tmp_path, "sim: {grip_width_mm: -1}\nfit: {note: x}\n")
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "world.yaml:1: sim.grip_width_mm: must be >= 0" in err and "Traceback" not in err
