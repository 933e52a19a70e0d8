"""``feeder commission`` against ``feeder emulate cell``, each its own process, as a person
does it: the person's hands are the emulator's standard input, their answers the
commissioning's (tests/support/commission_person.py plays the person)."""

from __future__ import annotations

import io
import json
import math
import socket

import numpy as np
import pytest
import yaml

from feeder_bt.cli.main import main
from tests.support.commission_person import (
    ROOT,
    Emulator,
    Person,
    PlateEmulator,
    commission,
    free_block,
    write_cell,
    write_plate_cell,
)


@pytest.fixture
def cell_and_emulator(tmp_path):
    port = free_block()
    cell = write_cell(tmp_path, port)
    emu = Emulator(cell, port)
    try:
        yield cell, emu
    finally:
        emu.stop()


def _steps(report) -> dict[str, dict]:
    data = json.loads(report.read_text())
    return {s["step"]: s for s in data["steps"]}


@pytest.mark.soak      # real time: two processes and a person
def test_commission_galil_every_step_with_the_persons_hands(cell_and_emulator, tmp_path):
    cell, emu = cell_and_emulator
    report = tmp_path / "galil.json"
    person = Person(emu)
    code, out = commission("galil", cell, report, person)
    steps = _steps(report)
    assert code == 0 and json.loads(report.read_text())["ok"], out
    assert list(steps)[:5] == ["galil.connect", "galil.firmware", "galil.programs",
                               "galil.input.jam", "galil.output.backlight"], out
    assert {f"galil.limit.{c}.{d}" for c in ("horizontal", "incline")
            for d in ("forward", "reverse")} <= set(steps)
    assert "DMC-21x3" in steps["galil.firmware"]["firmware"]
    assert steps["galil.input.jam"]["changes_seen"] >= 1
    assert steps["galil.output.backlight"]["seen_on"] and steps["galil.output.backlight"]["seen_off"]
    assert steps["galil.limit.horizontal.forward"]["operand"] == "_LFB"
    # pushed 50 mm by hand with the motor off: the count rose by 50 mm of counts
    enc = steps["galil.encoder.horizontal"]
    assert enc["encoder_direction"] == "up" and enc["mm"] == pytest.approx(50.0, abs=1.0)
    latch = steps["galil.latch"]
    assert latch["axis"] == "B" and latch["input"] == 2
    assert latch["latched"] == pytest.approx(latch["position_now"], abs=2)
    assert steps["galil.axis.horizontal"]["mm"] > 5
    # the person's hands went through the emulator: every action answered "ok"
    done = [a for a, _ in person.actions]
    assert "toggle jam" in done and "trigger" in done and "push horizontal 50" in done
    assert "press horizontal.forward_limit" in done


@pytest.mark.soak      # real time: two processes and a person
def test_commission_galil_fails_the_input_nobody_toggled(cell_and_emulator, tmp_path):
    cell, emu = cell_and_emulator
    report = tmp_path / "galil.json"
    code, out = commission("galil", cell, report, Person(emu, skip=("input.jam", "latch")),
                           "--input-wait", "1")
    steps = _steps(report)
    assert code == 1, out
    assert not steps["galil.input.jam"]["ok"] and steps["galil.input.jam"]["changes_seen"] == 0
    assert not steps["galil.latch"]["ok"] and "not tripped" in steps["galil.latch"]["error"]
    assert steps["galil.output.backlight"]["ok"]          # the rest went on


@pytest.mark.soak      # real time: two processes and a person
def test_commission_camera_calibration_and_timing(cell_and_emulator, tmp_path):
    cell, emu = cell_and_emulator
    report = tmp_path / "camera.json"
    code, out = commission("camera", cell, report, Person(emu))
    steps = _steps(report)
    assert code == 0, out
    assert steps["camera.grab"]["size"] == [640, 484]
    cal = steps["camera.calibration"]
    assert cal["rms_mm"] <= 0.5 and cal["points"] >= 40
    # the simulated camera truly maps a little off the cell file (sim.calib_*): the fit
    # finds a calibration close to, not equal to, the cell file's
    assert cal["calibration"]["origin_mm"] == pytest.approx([80.0, -15.0], abs=2.0)
    timing = steps["camera.timing"]
    assert abs(timing["delay_ms"]) <= 1.5 and timing["frames"] >= 6


def test_commission_camera_finds_a_target_laid_off_the_travel(cell_and_emulator, tmp_path):
    """The calibration target laid 2 deg off the belt's travel: the calibration fits it (a
    rigid target fits whatever its angle), the marker crossing the view shows the travel 2
    deg off the camera's x, the step says so, and the calibration it gives turned square to
    the travel maps the whole view within 1 mm of a target laid square."""
    from feeder_bt.core.model import CameraCalibration
    from feeder_bt.vision.pixels import Calibration
    cell, emu = cell_and_emulator
    straight, turned = tmp_path / "straight.json", tmp_path / "turned.json"
    code, out = commission("camera", cell, straight, Person(emu))
    assert code == 0, out
    code, out = commission("camera", cell, turned, Person(emu, target_turn_deg=2.0))
    assert code == 1, out
    good, bad = _steps(straight), _steps(turned)
    assert bad["camera.calibration"]["ok"]                 # the fit alone cannot tell
    assert abs(good["camera.timing"]["travel_deg"]) <= 0.1
    timing = bad["camera.timing"]
    assert not timing["ok"] and not timing["travel_ok"]
    assert abs(timing["travel_deg"]) == pytest.approx(2.0, abs=0.2)
    assert "laid turned" in timing["error"]

    def mapping(values: dict) -> np.ndarray:      # the similarity, as the step reports it
        cal = CameraCalibration(origin_mm=tuple(values["origin_mm"]),
                                mm_per_px=values["mm_per_px"],
                                rotation_deg=values["rotation_deg"])
        u, v = np.meshgrid(np.linspace(0, 639, 9), np.linspace(0, 483, 7))
        return Calibration(cal).px_to_mm(np.column_stack([u.ravel(), v.ravel()]))

    ref = mapping(good["camera.calibration"]["calibration"])
    as_fitted = np.hypot(*(mapping(bad["camera.calibration"]["calibration"]) - ref).T)
    squared = np.hypot(*(mapping(timing["calibration_square_to_travel"]) - ref).T)
    assert as_fitted.max() > 5.0                   # 2 deg at the corners of the view
    assert squared.max() <= 1.0, squared.max()


def test_commission_camera_finds_a_late_exposure(tmp_path):
    port = free_block()
    cell = write_cell(tmp_path, port)
    emu = Emulator(cell, port, "--camera-delay-ms", "10")
    try:
        report = tmp_path / "camera.json"
        code, out = commission("camera", cell, report, Person(emu))
    finally:
        emu.stop()
    timing = _steps(report)["camera.timing"]
    assert code == 1 and not timing["ok"], out
    assert timing["delay_ms"] == pytest.approx(10.0, abs=1.5)
    assert timing["delay_mm"] == pytest.approx(10.0 * 0.2, abs=0.3)      # at 200 mm/s


def test_commission_adept_io_sync_and_an_untouched_frame(cell_and_emulator, tmp_path):
    """Vacuum, grip sensor, e-stop and the sync pass; a person who never touches the marks
    gives no frame: the step fails, nothing is written, the arm does not move."""
    cell, emu = cell_and_emulator
    report = tmp_path / "adept.json"
    frame = tmp_path / "robot.yaml"
    person = Person(emu, skip=("touch.1", "touch.2", "touch.3"))
    code, out = commission("adept", cell, report, person, "--write", str(frame))
    steps = _steps(report)
    assert code == 1, out
    vac = steps["adept.vacuum"]
    assert vac["ok"], out
    assert not vac["sensor_without_part"] and vac["sensor_with_part"]
    assert steps["adept.estop"]["ok"] and steps["adept.estop"]["pressed_seen"]
    assert steps["adept.sync"]["ok"] and steps["adept.drift"]["ok"], out
    assert abs(steps["adept.drift"]["drift_counts"]) <= 10
    assert steps["adept.drift"]["belt_mm"] > 10
    assert not steps["adept.frame"]["ok"]
    assert not frame.exists()
    assert not any(k.startswith("adept.corner") for k in steps)
    assert ("power on", "ok arm power on") in person.actions


@pytest.mark.soak      # real time: two processes and a person
def test_commission_adept_fits_the_true_robot_base(tmp_path):
    """With the V+ emulator's pendant (FRAME_SPEC): the fitted base is the true one."""
    from feeder_bt.emulators.adept import AdeptEmulator
    if not hasattr(AdeptEmulator, "pendant_to_cell"):
        pytest.skip("needs the vplus branch's AdeptEmulator.pendant_to_cell and HERE")
    port = free_block()
    cell = write_cell(tmp_path, port)
    emu = Emulator(cell, port, "--robot-error", "5", "-3", "2")
    frame = tmp_path / "calibration" / "robot.yaml"
    try:
        report = tmp_path / "adept.json"
        # the window's prompt is the one the fitted base (5 mm downstream of the cell
        # file's) reaches, from 775 mm; the person teaches the upstream limit 10 mm inside
        person = Person(emu, miss={"window.up": (10.0, 0.0)})
        code, out = commission("adept", cell, report, person, "--write", str(frame))
    finally:
        emu.stop()
    steps = _steps(report)
    assert code == 0, out
    assert steps["adept.window"]["ok"] and steps["adept.window"]["sent"]
    assert steps["adept.window"]["taught_mm"] == pytest.approx([785.0, 1219.0, 1219.0], abs=0.5)
    fit = steps["adept.frame"]
    assert fit["base_mm"] == pytest.approx([1375.0, 302.0], abs=0.5)
    assert fit["base_deg"] == pytest.approx(2.0, abs=0.1)
    assert fit["change_from_cell_file"]["dx_mm"] == pytest.approx(5.0, abs=0.5)
    written = yaml.safe_load(frame.read_text())
    assert written["base_mm"] == pytest.approx([1375.0, 302.0], abs=0.5)
    assert {f"adept.corner{i}" for i in range(1, 5)} <= set(steps)


def test_commission_adept_refuses_a_frame_that_does_not_fit(tmp_path):
    """One mark touched 6 mm off: the residual is over the limit, nothing is written and
    the arm does not move."""
    from feeder_bt.emulators.adept import AdeptEmulator
    if not hasattr(AdeptEmulator, "pendant_to_cell"):
        pytest.skip("needs the vplus branch's AdeptEmulator.pendant_to_cell and HERE")
    port = free_block()
    cell = write_cell(tmp_path, port)
    emu = Emulator(cell, port, "--robot-error", "5", "-3", "2")
    frame = tmp_path / "robot.yaml"
    try:
        report = tmp_path / "adept.json"
        code, out = commission("adept", cell, report, Person(emu, miss={"touch.2": (6.0, 0.0)}),
                               "--write", str(frame))
    finally:
        emu.stop()
    steps = _steps(report)
    assert code == 1, out
    fit = steps["adept.frame"]
    assert not fit["ok"] and fit["rms_mm"] > 1.0 and fit["written"] is None
    assert not frame.exists()
    assert not any(k.startswith("adept.corner") for k in steps)


def test_commission_plate_every_step_against_an_echoing_feeder(tmp_path):
    """``feeder commission plate`` against ``feeder emulate plate --echo`` (motor 2
    reporting 0.2 s after motor 1), the person watching the plate (``look``): the echo
    is found, every action runs and is confirmed, the parameters are read back."""
    port = free_block(1)
    cell = write_plate_cell(tmp_path, port)
    emu = PlateEmulator(cell, port, "--echo", "--motor-gap", "0.2")
    try:
        report = tmp_path / "plate.json"
        person = Person(emu)
        code, out = commission("plate", cell, report, person)
    finally:
        emu.stop()
    steps = _steps(report)
    assert code == 0 and json.loads(report.read_text())["ok"], out
    assert list(steps) == ["plate.connect", "plate.init", "plate.parameters",
                           "plate.dispense", "plate.feed_forward", "plate.feed_backward",
                           "plate.flip", "plate.flip_forward", "plate.flip_backward",
                           "plate.heavy_dispense", "plate.purge", "plate.reset",
                           "plate.stop"], out
    assert steps["plate.connect"]["echo"] is True
    assert steps["plate.init"]["command"] == "x=16" and steps["plate.reset"]["command"] == "x=30"
    assert sorted(steps["plate.dispense"]["replies"]) == ["m10", "m11", "m20", "m21"]
    written = steps["plate.parameters"]["written"]
    assert written["ab[17]"]["value"] == 5 and written["ab[23]"]["value"] == 3
    assert written["ab[8]"] == {"what": "heavy_dispense repetitions", "value": 2,
                                "answer": []}
    assert all(s["seen"] for k, s in steps.items() if "seen" in s)
    assert [a for a, _ in person.actions].count("look") == 10


def test_the_emulator_serves_on_after_its_standard_input_ends(cell_and_emulator):
    cell, emu = cell_and_emulator
    assert emu.act("help").startswith("ok actions:")
    assert emu.act("bogus 1").startswith("error: unknown action 'bogus'")
    assert emu.act("toggle nosuch").startswith("error: toggle: no input 'nosuch'")
    assert emu.act("push horizontal fast").startswith("error: push: MM: expected a number")
    emu.p.stdin.close()                                  # CI: no standard input
    assert "serving on" in emu.line()
    port = yaml.safe_load(cell.read_text())["adept"]["motion_port"] - 1
    socket.create_connection(("127.0.0.1", port), timeout=10).close()
    assert emu.p.poll() is None


# ------------------------------------------------------------------------------ pieces


def test_frame_fit_recovers_a_turned_and_moved_base():
    from feeder_bt.cli.commission.frame import fit_frame
    a = math.radians(2.0)
    base = (1375.0, 302.0)
    cell_pts = [(903.0, 50.0), (903.0, 560.0), (1169.0, 305.0), (1000.0, 200.0)]
    noise = [(0.1, -0.05), (-0.08, 0.1), (0.0, -0.1), (0.05, 0.05)]
    robot_pts = []
    for (x, y), (nx, ny) in zip(cell_pts, noise, strict=True):
        dx, dy = x - base[0], y - base[1]
        robot_pts.append((math.cos(a) * dx + math.sin(a) * dy + nx,
                          -math.sin(a) * dx + math.cos(a) * dy + ny))
    fit = fit_frame(cell_pts, robot_pts)
    assert fit.base_mm == pytest.approx(base, abs=0.3)
    assert fit.base_deg == pytest.approx(2.0, abs=0.03)
    assert 0.0 < fit.rms_mm < 0.2
    with pytest.raises(ValueError, match="coincide"):
        fit_frame(cell_pts[:3], [(10.0, 10.0)] * 3)


def test_the_robot_frame_file_replaces_the_cells_base(tmp_path):
    from feeder_bt.config import load_cell
    from feeder_bt.core.errors import ConfigError
    data = yaml.safe_load((ROOT / "cells" / "sim.yaml").read_text())
    data["robot"]["frame_file"] = "calibration/robot.yaml"
    (tmp_path / "cell.yaml").write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"robot.frame_file.*not found"):
        load_cell(tmp_path / "cell.yaml")
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "robot.yaml").write_text(
        "base_mm: [1372.5, 301.0]\nbase_deg: 0.0\nrms_mm: 0.2\n")
    assert load_cell(tmp_path / "cell.yaml").robot.base_mm == (1372.5, 301.0)
    (tmp_path / "calibration" / "robot.yaml").write_text("base_mm: [1372.5, 301.0]\n"
                                                         "base_deg: 1.5\n")
    if hasattr(load_cell(ROOT / "cells" / "sim.yaml").robot, "base_deg"):
        assert load_cell(tmp_path / "cell.yaml").robot.base_deg == 1.5
    else:                                # before the frame contract's RobotSpec.base_deg
        with pytest.raises(ConfigError, match="no robot.base_deg"):
            load_cell(tmp_path / "cell.yaml")
    (tmp_path / "calibration" / "robot.yaml").write_text("base_mm: [1372.5]\nbase_deg: 0\n")
    with pytest.raises(ConfigError, match=r"robot.yaml:1: base_mm: expected \[x, y\]"):
        load_cell(tmp_path / "cell.yaml")


def test_fresh_anchor_pairs_only_fresh_counts_at_rest():
    from feeder_bt.core.encoder import FreshAnchor
    a = FreshAnchor(32, 24, max_age_s=0.5)
    assert a.offer(10.0, 1000, 2.0, 50, 0.0) is None and "not fresh" in a.why
    assert a.offer(10.1, 1000, 0.05, 50, 0.02) is None          # one read of each so far
    assert a.offer(10.2, 1040, 0.05, 52, 0.02) is None and "moving" in a.why
    assert a.offer(10.3, 1040, 0.05, 52, 0.12) is None           # same robot read: not new
    assert a.offer(10.4, 1040, 0.05, 52, 0.02) == (1040, 52)


def test_questions_are_answered_from_the_file_then_standard_input():
    from feeder_bt.cli.commission import Asker
    out = io.StringIO()
    ask = Asker({"latch": "done"}, io.StringIO("yes\n"), out)
    assert ask("latch", "Fire the trigger") == "done"             # from the answers file
    assert ask.yes("direction.horizontal", "Forward?")            # from standard input
    assert not ask.yes("direction.incline", "Forward?")           # end of input: the default
    assert "(no answer: no)" in out.getvalue()


def test_commission_reports_a_bad_answers_file_in_one_line(tmp_path, capsys):
    bad = tmp_path / "answers.yaml"
    bad.write_text("- a list\n")
    code = main(["commission", "camera", str(ROOT / "cells" / "sim.yaml"), "--answers",
                 str(bad), "--report", str(tmp_path / "r.yaml")])
    err = capsys.readouterr().err
    assert code == 2 and "answers must be a mapping" in err and "Traceback" not in err


def test_a_runs_sync_waits_for_fresh_reads_and_says_why_it_gave_up():
    """The run's set-up anchors as commissioning does: a stale cached count is never used."""
    from types import SimpleNamespace

    from py_trees.common import Status

    from feeder_bt.behaviours.setup import SyncEncoders
    from feeder_bt.core.clock import SimClock
    from feeder_bt.core.encoder import EncoderSync

    clock = SimClock()
    conv = SimpleNamespace(count=5000, age=3.0)
    conveyor = SimpleNamespace(position=lambda: conv.count, position_age=lambda: conv.age)
    robot = SimpleNamespace(belt_encoder=lambda: 77, age=lambda: 0.0)
    sync = EncoderSync()
    ctx = SimpleNamespace(cell=SimpleNamespace(encoder=SimpleNamespace(conveyor_bits=32,
                                                                      robot_bits=24)),
                          hal=SimpleNamespace(conveyors={"horizontal": conveyor},
                                              robot_position=robot),
                          encoder=sync, clock=clock, now=clock.now)
    leaf = SyncEncoders("sync", ctx, timeout_s=1.0)      # type: ignore[arg-type]
    leaf.initialise()
    for _ in range(5):                                    # the Galil's count is 3 s old
        clock.advance_to(clock.now() + 0.1)
        assert leaf.update() is Status.RUNNING
    assert not sync.is_reset
    conv.age = 0.0                                        # fresh reads come
    clock.advance_to(clock.now() + 0.1)
    assert leaf.update() is Status.RUNNING                # one fresh read is not two
    clock.advance_to(clock.now() + 0.1)
    assert leaf.update() is Status.SUCCESS and sync.reference == (5000, 77)
    leaf.initialise()
    conv.age = 3.0
    while leaf.update() is Status.RUNNING:
        clock.advance_to(clock.now() + 0.1)
    assert "not fresh" in leaf.feedback_message and "1 s" in leaf.feedback_message
