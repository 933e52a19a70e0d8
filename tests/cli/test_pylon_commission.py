"""``feeder commission camera`` on a pylon camera, against Basler's camera emulator serving
the simulated cell's image of the calibration target: it finds the camera, checks one
frame per trigger, the exposure against the belt speed, grabs calibration views and fits
the calibration; an exposure that would smear a part over half a pixel is refused."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from feeder_bt.cli.commission.pylon_steps import blur
from feeder_bt.cli.main import main

pytest.importorskip("pypylon", reason="pypylon is not installed (pip install -e '.[pylon]')")

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def camemu(monkeypatch):
    monkeypatch.setenv("PYLON_CAMEMU", "1")


def pylon_cell(tmp_path: Path, exposure_ms: float) -> Path:
    """cells/sim.yaml with a pylon camera serving the target, as the simulated camera
    draws it lying centred in the view (what the calibration step asks the person for)."""
    from feeder_bt.calibration.camera import centred_pose
    from feeder_bt.cli.commission.camera import cell_target
    from feeder_bt.config.loader import load_cell
    from feeder_bt.core.images import write_image
    from feeder_bt.sim.target import TargetCamera

    cell = load_cell(ROOT / "cells" / "sim.yaml", calibration_files=False)
    cam = cell.camera
    target_cam = TargetCamera(cam)
    target_cam.place(cell_target(cell), centred_pose(cam.calibration, cam.width_px,
                                                     cam.height_px))
    images = tmp_path / "served"
    write_image(images / "target.png", target_cam.grab().result.image)
    text = (ROOT / "cells" / "sim.yaml").read_text().replace(
        "  exposure_ms: 2.0\n",
        f"  exposure_ms: {exposure_ms}\n  source: 'pylon:'\n"
        f"  pylon: {{trigger: Software, frame_timeout_s: 10, emulator_images: '{images}'}}\n", 1)
    path = tmp_path / "cell.yaml"
    path.write_text(text)
    return path


def commission(tmp_path: Path, cell: Path, *extra: str) -> tuple[int, dict[str, dict]]:
    report = tmp_path / "camera.json"
    answers = tmp_path / "answers.yaml"
    answers.write_text("target.lay: ok\ntarget.remove: ok\nview.1: ok\nview.2: ok\n")
    code = main(["commission", "camera", str(cell), "--answers", str(answers), "--report",
                 str(report), "--steps", "enumerate,grab,trigger,exposure,views,calibration",
                 "--views", "2", "--views-dir", str(tmp_path / "views"), *extra])
    data = json.loads(report.read_text())
    return code, {s["step"]: s for s in data["steps"]}


def test_commission_a_pylon_camera_passes_and_writes_its_report(tmp_path, capsys):
    code, steps = commission(tmp_path, pylon_cell(tmp_path, exposure_ms=1.0))
    out = capsys.readouterr().out
    assert code == 0, out
    assert list(steps) == ["camera.pylon.enumerate", "camera.grab", "camera.pylon.trigger",
                           "camera.pylon.exposure", "camera.pylon.views",
                           "camera.calibration"]
    assert steps["camera.pylon.enumerate"]["cameras"][0]["class"] == "BaslerCamEmu"
    assert steps["camera.grab"]["size"] == [640, 484]
    trig = steps["camera.pylon.trigger"]
    assert trig["frames"] == 10 and trig["lost_frames"] == 0 and trig["extra_triggers"] == 0
    exp = steps["camera.pylon.exposure"]
    # 1 ms at 400 mm/s (the horizontal belt's max) and ~1 mm/px: 0.4 px; 1.25 ms the longest
    assert exp["exposure_ms"] == pytest.approx(1.0)
    assert exp["blur_px"] == pytest.approx(0.4, abs=0.01)
    assert exp["longest_exposure_ms"] == pytest.approx(1.25, abs=0.01)
    views = steps["camera.pylon.views"]["views"]
    assert len(views) == 2 and all(Path(v).stat().st_size > 1000 for v in views)
    assert steps["camera.calibration"]["rms_mm"] <= 0.5


def test_commission_refuses_an_exposure_that_blurs(tmp_path, capsys):
    code, steps = commission(tmp_path, pylon_cell(tmp_path, exposure_ms=2.0))
    assert code == 1
    exp = steps["camera.pylon.exposure"]
    assert exp["ok"] is False and exp["blur_px"] == pytest.approx(0.8, abs=0.01)
    assert exp["longest_exposure_ms"] == pytest.approx(1.25, abs=0.01)
    # a slower belt takes the same exposure
    code, steps = commission(tmp_path, pylon_cell(tmp_path, exposure_ms=2.0),
                             "--belt-mm-s", "200")
    assert code == 0 and steps["camera.pylon.exposure"]["blur_px"] == pytest.approx(0.4,
                                                                                    abs=0.01)


def test_blur_is_exposure_times_speed_over_pixel_size():
    b = blur(exposure_ms=0.5, speed_mm_s=100.0, mm_per_px=0.2)
    assert b["blur_px"] == pytest.approx(0.25) and b["ok"]
    assert b["longest_exposure_ms"] == pytest.approx(1.0)
    assert not blur(1.0, 100.0, 0.2)["ok"]
