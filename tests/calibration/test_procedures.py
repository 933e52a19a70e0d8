"""Guided calibration (feeder_bt.calibration) on the simulated cell and on synthetic data.

The simulated camera maps pixels by a *truth* calibration that differs from the cell file;
the procedures see only pixels, robot poses and encoder counts, and must recover it.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from feeder_bt.calibration import (
    DEFAULT_TARGETS,
    BeltTouch,
    CalibrationError,
    ToolTouch,
    apply_calibration_file,
    calibrate_camera_image,
    fit_belt,
    fit_camera,
    fit_tool,
    window_error_mm,
)
from feeder_bt.calibration.belt import unwrap_counts
from feeder_bt.calibration.camera import TargetPose, centred_pose, target_points_mm
from feeder_bt.cli import calibrate
from feeder_bt.cli.main import _Parser
from feeder_bt.config import load_cell
from feeder_bt.core.errors import ConfigError, FeederError
from feeder_bt.core.model import CameraCalibration
from feeder_bt.sim.target import TargetCamera, target_polygons
from feeder_bt.vision.pixels import Calibration

ROOT = Path(__file__).resolve().parents[2]
SIM_CELL = ROOT / "cells" / "sim.yaml"


@pytest.fixture(scope="module")
def cell():
    return load_cell(SIM_CELL)


def _truth(cell) -> CameraCalibration:
    # origin off by a few mm, turned 0.4 deg, scale 1.5 % off
    return calibrate.sim_truth(cell.camera.calibration, 3.0, -2.0, 0.4, 1.5)


def _cli(argv: list[str]) -> int:
    p = _Parser(prog="feeder")
    sub = p.add_subparsers(dest="command", required=True, parser_class=_Parser)
    calibrate.add_parser(sub)
    args = p.parse_args(argv)
    try:
        return args.handler(args)
    except FeederError as e:
        print(f"feeder: {e}")
        return e.exit_code


# ----------------------------------------------------------------------------- camera


@pytest.mark.parametrize("kind", ["chessboard", "dots"])
def test_camera_recovers_a_truth_that_differs_from_the_cell_file(cell, kind):
    cam = cell.camera
    truth = _truth(cell)
    nominal_off = window_error_mm(cam.calibration, truth, cam.width_px, cam.height_px)
    assert nominal_off > 5.0          # the cell file really is wrong by several mm
    target = DEFAULT_TARGETS[kind]
    pose = centred_pose(cam.calibration, cam.width_px, cam.height_px)
    fit = calibrate.sim_camera(cell, target, pose, truth, seed=3)
    assert fit.n_points == target.nx * target.ny
    assert fit.rms_mm < 0.5 and fit.max_mm < 0.5
    assert window_error_mm(fit.calibration, truth, cam.width_px, cam.height_px) < 0.5
    assert fit.calibration.rotation_deg == pytest.approx(0.4, abs=0.05)
    assert fit.calibration.mm_per_px == pytest.approx(truth.mm_per_px, rel=1e-3)
    assert fit.hint is None


def test_camera_with_a_turned_target(cell):
    cam = cell.camera
    truth = _truth(cell)
    c = centred_pose(cam.calibration, cam.width_px, cam.height_px)
    pose = TargetPose(c.x_mm + 10.0, c.y_mm - 5.0, 3.0)
    fit = calibrate.sim_camera(cell, DEFAULT_TARGETS["chessboard"], pose, truth, seed=1)
    assert window_error_mm(fit.calibration, truth, cam.width_px, cam.height_px) < 0.5


def test_fit_camera_is_exact_on_exact_points_and_matches_the_convention():
    truth = CameraCalibration(origin_mm=(100.0, -20.0), mm_per_px=0.8, rotation_deg=-1.3)
    rng = np.random.default_rng(0)
    px = rng.uniform(0, 600, size=(20, 2))
    mm = Calibration(truth).px_to_mm(px)
    fit = fit_camera(px, mm)
    assert fit.rms_mm < 1e-9
    assert fit.calibration.origin_mm == pytest.approx(truth.origin_mm)
    assert fit.calibration.mm_per_px == pytest.approx(0.8)
    assert fit.calibration.rotation_deg == pytest.approx(-1.3)


def test_tilted_camera_is_hinted():
    u, v = np.meshgrid(np.linspace(0, 640, 9), np.linspace(0, 480, 7))
    px = np.column_stack([u.ravel(), v.ravel()])
    h = np.array([[0.0, 1.0, 80.0], [1.0, 0.0, -15.0], [4e-5, 0.0, 1.0]])   # perspective
    q = np.column_stack([px, np.ones(len(px))]) @ h.T
    mm = q[:, :2] / q[:, 2:]
    fit = fit_camera(px, mm)
    assert fit.rms_mm > 1.0 and fit.homography_rms_mm < 1e-3
    assert fit.hint is not None and "tilted" in fit.hint


def test_target_polygons_are_dark_squares_inside_the_window(cell):
    cam = cell.camera
    target = DEFAULT_TARGETS["chessboard"]
    pose = centred_pose(cam.calibration, cam.width_px, cam.height_px)
    polys = target_polygons(target, pose)
    assert len(polys) == math.ceil((target.nx + 1) * (target.ny + 1) / 2)
    px = Calibration(cam.calibration).mm_to_px(np.vstack(polys))
    assert px.min() > 0 and px[:, 0].max() < cam.width_px and px[:, 1].max() < cam.height_px
    corners = target_points_mm(target, pose).reshape(-1, 2)
    assert np.allclose(corners.mean(axis=0), [pose.x_mm, pose.y_mm])


# ----------------------------------------------------------------------------- belt and tool


def test_belt_recovers_counts_per_mm_and_direction_across_a_wrap(cell):
    start = 2 ** 23 - 2000                       # the 24-bit robot counter wraps mid-procedure
    wrapping = dataclasses.replace(cell, encoder=dataclasses.replace(cell.encoder,
                                                                     robot_start=start))
    fit = calibrate.sim_belt(wrapping, seed=2, noise_mm=0.1, counts_per_mm=20.1, frame_deg=0.7)
    assert fit.counts_per_mm == pytest.approx(20.1, rel=0.005)
    assert fit.direction_deg == pytest.approx(0.7, abs=0.2)
    assert fit.rms_mm < 0.5
    assert fit.travel_mm == pytest.approx(320.0, rel=0.01)


def test_unwrap_counts_across_the_24_bit_roll_over():
    assert list(unwrap_counts([2 ** 23 - 10, -(2 ** 23) + 5, -(2 ** 23) + 25], 24)) == [0, 15, 35]


def test_tool_offset_recovered(cell):
    fit = calibrate.sim_tool(cell, (12.0, -5.0), seed=4, noise_mm=0.1)
    assert math.dist(fit.offset_mm, (12.0, -5.0)) < 0.2
    assert math.dist(fit.point_mm, calibrate.TOOL_POINT_MM) < 0.2
    assert fit.rms_mm < 0.5


def test_tool_two_touches_half_a_turn_apart_are_enough():
    d, p = np.array([10.0, 3.0]), np.array([500.0, 200.0])
    touches = []
    for rz in (0.0, 180.0):
        r = math.radians(rz)
        f = p - np.array([[math.cos(r), -math.sin(r)], [math.sin(r), math.cos(r)]]) @ d
        touches.append(ToolTouch(f[0], f[1], rz))
    fit = fit_tool(touches)
    assert fit.offset_mm == pytest.approx((10.0, 3.0))


# ----------------------------------------------------------------------------- bad inputs


def test_too_few_camera_points():
    with pytest.raises(CalibrationError, match="at least 4"):
        fit_camera([[0, 0], [1, 0], [0, 1]], [[0, 0], [1, 0], [0, 1]])


def test_collinear_camera_points():
    px = [[i, 2 * i] for i in range(6)]
    with pytest.raises(CalibrationError, match="on one line"):
        fit_camera(px, px)


def test_no_chessboard_in_the_image(cell):
    cam = TargetCamera(cell.camera, seed=1)          # nothing on the belt
    img = cam.grab().result.image
    pose = centred_pose(cell.camera.calibration, 640, 484)
    with pytest.raises(CalibrationError, match="no chessboard of 8x12 inner corners") as e:
        calibrate_camera_image(img, DEFAULT_TARGETS["chessboard"], pose,
                               cell.camera.calibration)
    assert "\n" not in str(e.value)


def test_target_far_from_its_stated_pose(cell):
    cam = cell.camera
    c = centred_pose(cam.calibration, cam.width_px, cam.height_px)
    camera = TargetCamera(cam, seed=1)
    camera.place(DEFAULT_TARGETS["chessboard"], TargetPose(c.x_mm + 25.0, c.y_mm))
    img = camera.grab().result.image
    with pytest.raises(CalibrationError, match="half a pitch"):
        calibrate_camera_image(img, DEFAULT_TARGETS["chessboard"], c, cam.calibration)


def test_belt_bad_inputs():
    with pytest.raises(CalibrationError, match="at least 3 touches"):
        fit_belt([BeltTouch(0, 0, 0), BeltTouch(10, 0, 200)])
    with pytest.raises(CalibrationError, match="did not change"):
        fit_belt([BeltTouch(0, 0, 5), BeltTouch(0, 0, 5), BeltTouch(0, 0, 5)])
    with pytest.raises(CalibrationError, match="only 2.0 mm"):
        fit_belt([BeltTouch(0, 0, 0), BeltTouch(1, 0, 20), BeltTouch(2, 0, 40)])


def test_tool_bad_inputs():
    with pytest.raises(CalibrationError, match="at least 2 touches"):
        fit_tool([ToolTouch(0, 0, 0)])
    with pytest.raises(CalibrationError, match="span only 5.0 deg"):
        fit_tool([ToolTouch(0, 0, 0), ToolTouch(1, 0, 5), ToolTouch(2, 0, 2)])


# ----------------------------------------------------------------------------- files and CLI


def _cell_naming(tmp_path: Path, calib: str) -> Path:
    text = SIM_CELL.read_text().replace("  exposure_ms: 2.0",
                                        f"  exposure_ms: 2.0\n  calibration_file: {calib}")
    dest = tmp_path / "cell.yaml"
    dest.write_text(text)
    return dest


def test_cli_writes_the_file_the_cell_names_and_the_cell_uses_it(tmp_path, capsys):
    cell_file = _cell_naming(tmp_path, "calib/camera.yaml")
    rc = _cli(["calibrate", "camera", str(cell_file), "--sim-truth", "3", "-2", "0.4", "1.5",
               "--write"])
    out = capsys.readouterr().out
    assert rc == 0 and "belt plane over 96 points" in out
    written = tmp_path / "calib" / "camera.yaml"
    assert written.is_file()
    nominal = load_cell(cell_file, calibration_files=False)
    applied = load_cell(cell_file)               # the loader applies the file the cell names
    truth = calibrate.sim_truth(calibrate.true_camera(nominal), 3.0, -2.0, 0.4, 1.5)
    assert window_error_mm(applied.camera.calibration, truth, 640, 484) < 0.5
    assert applied.camera.calibration.intrinsics is not None    # the lens, in the file
    assert apply_calibration_file(load_cell(SIM_CELL)).camera.calibration == \
        load_cell(SIM_CELL).camera.calibration


@pytest.mark.parametrize("body, expect", [
    ("mm_per_px: 1.0\nrotation_deg: 0\n", "camera.yaml:1: missing required key 'origin_mm'"),
    ("origin_mm: [1, 2]\nmm_per_px: -1\nrotation_deg: 0\n", "camera.yaml:2: mm_per_px: must be > 0"),
    ("origin_mm: [1]\nmm_per_px: 1\nrotation_deg: 0\n", "camera.yaml:1: origin_mm: expected [x, y]"),
    ("origin_mm: [1, 2]\nmm_per_px: 1\nrotation_deg: abc\n", "camera.yaml:3: rotation_deg: expected a finite number"),
])
def test_bad_calibration_files(tmp_path, body, expect):
    (tmp_path / "camera.yaml").write_text(body)
    with pytest.raises(ConfigError) as e:
        load_cell(_cell_naming(tmp_path, "camera.yaml"))
    assert expect in str(e.value) and "\n" not in str(e.value)


def test_missing_calibration_file_names_the_cell_key(tmp_path):
    with pytest.raises(ConfigError, match=r"cell.yaml:\d+: camera.calibration_file: .*not found"):
        load_cell(_cell_naming(tmp_path, "nowhere.yaml"))


def test_cli_belt_and_tool_write_yaml(tmp_path, capsys):
    assert _cli(["calibrate", "belt", str(SIM_CELL), "--write", str(tmp_path / "b.yaml")]) == 0
    assert _cli(["calibrate", "tool", str(SIM_CELL), "--sim-tool", "8", "0",
                 "--write", str(tmp_path / "t.yaml")]) == 0
    out = capsys.readouterr().out
    assert "counts_per_mm 20.0" in out and "tool: offset [8.0" in out
    assert "counts_per_mm: 20.0" in (tmp_path / "b.yaml").read_text()


def test_cli_real_cell_camera_needs_a_photo(tmp_path, capsys):
    real = tmp_path / "real.yaml"
    real.write_text(SIM_CELL.read_text().replace("hal: sim", "hal: real"))
    assert _cli(["calibrate", "camera", str(real)]) == 2
    out = capsys.readouterr().out.strip()
    assert "give the photo with --image" in out and "\n" not in out


@pytest.mark.parametrize("what", ["belt", "tool"])
def test_cli_real_cell_belt_and_tool_go_through_the_drivers(tmp_path, capsys, what):
    """On a real cell the procedures connect to the controllers (here: nobody listens on
    the cell's ports): one line naming the controller, a non-zero exit."""
    real = tmp_path / "real.yaml"
    real.write_text(SIM_CELL.read_text().replace("hal: sim", "hal: real")
                    + "adept: {host: 127.0.0.1, motion_port: 9, position_port: 9, "
                      "io_port: 9, notify_port: 9, timeout_s: 1}\n"
                    + "galil: {url: 'socket://127.0.0.1:9', timeout_s: 1}\n")
    assert _cli(["calibrate", what, str(real)]) != 0
    out = capsys.readouterr().out.strip()
    # refused while connecting, or still backing off when the time-out came: either way
    # one line naming the server (which one depends on the machine's speed)
    assert ("not connected" in out or "cannot connect" in out) and "\n" not in out
    assert "127.0.0.1:9" in out


def test_cli_write_without_file_or_cell_key(capsys):
    assert _cli(["calibrate", "camera", str(SIM_CELL), "--write"]) == 2
    assert "names no camera.calibration_file" in capsys.readouterr().out


def test_cli_is_a_subcommand():
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="command")
    calibrate.add_parser(sub)
    args = p.parse_args(["calibrate", "tool", "x.yaml", "--seed", "5"])
    assert args.what == "tool" and args.seed == 5 and args.handler is calibrate.cmd_calibrate
