"""The world's arm moves like a SCARA (feeder_bt/robot/scara.py): times against
hand-computed joint profiles, and the selection-aware robot bounds over a run's record."""

from __future__ import annotations

import math
import tempfile
from pathlib import Path

import numpy as np
import pytest

from feeder_bt.analysis.robot_bounds import Pricing, mean_bound, selection_bound
from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config import load_cell, load_scenario
from feeder_bt.robot.model import RobotModel
from feeder_bt.robot.scara import RAMP_S, ScaraModel, ScaraSpec, world_arm
from feeder_bt.sim.passlog import PassLog

ROOT = Path(__file__).resolve().parents[2]
CELL = load_cell(ROOT / "cells" / "sim.yaml")
BX, BY = CELL.robot.base_mm            # base_deg 0: the robot's frame is the cell's, shifted


def at(r: float, deg: float) -> tuple[float, float]:
    """A cell point ``r`` mm from the base at ``deg`` in the robot's frame."""
    return BX + r * math.cos(math.radians(deg)), BY + r * math.sin(math.radians(deg))


def trap(d: float, v: float, ramp: float) -> float:
    """A rest-to-rest profile by hand: full speed after ``ramp`` s (a = v / ramp)."""
    a = v / ramp
    return 2 * math.sqrt(d / a) if d < v * ramp else ramp + d / v


# Z: 25 mm at 1100 mm/s reaching full speed in RAMP_S: short, a triangle
Z_T = trap(25.0, 1100.0, RAMP_S)
Z_RAMP = Z_T / 2


def test_a_pure_joint_1_rotation():
    """Both ends 400 mm from the base, 60 degrees apart: the elbow keeps its angle, joint 1
    turns 60 degrees at 386 deg/s. The arch: up, across, down, each acceleration
    overlapping the previous deceleration."""
    arm = ScaraModel(CELL.robot)              # the Cobra 600's own figures
    a, b = at(400.0, 150.0), at(400.0, 210.0)
    across = trap(60.0, 386.0, RAMP_S)
    assert across == pytest.approx(RAMP_S + 60 / 386)           # it cruises
    expect = 2 * Z_T + across - 2 * min(Z_RAMP, RAMP_S)
    assert arm.move_time(a, b, 100.0) == pytest.approx(expect, rel=1e-9)
    assert arm.move_time(b, a, 100.0) == pytest.approx(expect, rel=1e-9)   # symmetric


def test_a_radial_move_is_elbow_limited():
    """From 200 to 590 mm along one direction the elbow opens by far more than joint 1
    turns: joint 2 (720 deg/s) sets the time. Angles by the law of cosines."""
    arm = ScaraModel(CELL.robot)
    l1, l2 = 325.0, 275.0

    def elbow(r: float) -> float:
        return math.degrees(math.acos((r * r - l1 * l1 - l2 * l2) / (2 * l1 * l2)))

    def shoulder(r: float) -> float:          # joint 1's offset from the point's bearing
        q2 = math.radians(elbow(r))
        return math.degrees(math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2)))

    d2 = elbow(200.0) - elbow(590.0)
    d1 = shoulder(200.0) - shoulder(590.0)
    assert d2 == pytest.approx(121.2, abs=0.1) and d1 < d2
    t1, t2 = trap(d1, 386.0, RAMP_S), trap(d2, 720.0, RAMP_S)
    assert t2 > t1                                                 # the elbow limits
    expect = 2 * Z_T + t2 - 2 * min(Z_RAMP, RAMP_S)
    assert arm.move_time(at(200.0, 170.0), at(590.0, 170.0), 100.0) == pytest.approx(expect)


def test_speed_scales_every_joint_and_the_calibration():
    """SPEED s %: speeds times s, accelerations times s squared, so every time is 1/s;
    the Adept cycle (25/305/25 mm there and back) is 0.5 s at 100 % for the Cobra 600's
    figures, and the world's arm keeps the cell's own calibration (its Cartesian model's
    cycle: 0.5 s on the new cell, 0.7 s for the original cell's Adept 550)."""
    assert ScaraModel(CELL.robot).standard_cycle() == pytest.approx(0.5, abs=1e-4)
    old = load_cell(ROOT / "cells" / "original_cwru.yaml").robot
    for spec in (CELL.robot, old):
        assert world_arm(spec).standard_cycle() == pytest.approx(
            RobotModel(spec).standard_cycle(), rel=1e-9)
    assert world_arm(old).scara.inner_mm + world_arm(old).scara.outer_mm == old.reach_mm
    arm = world_arm(CELL.robot)
    a, b = (900.0, 150.0), (1330.0, -120.0)
    assert arm.move_time(a, b, 50.0) == pytest.approx(2 * arm.move_time(a, b, 100.0))
    assert world_arm(CELL.robot, 0.5).move_time(a, b, 100.0) == pytest.approx(
        2 * arm.move_time(a, b, 100.0))
    # the vectorised form agrees with the scalar one
    xs, ys = np.array([900.0, 1100.0, 1190.0]), np.array([100.0, 305.0, 560.0])
    many = arm.arch_times_from(b, xs, ys, 80.0)
    assert many == pytest.approx([arm.move_time(b, (x, y), 80.0) for x, y in zip(xs, ys, strict=True)])


def test_a_scara_is_not_the_controllers_cartesian_model():
    """Two moves of the same length from the place pose, one across the robot's front
    and one along its radius, take different times: no model of distance alone fits."""
    arm = world_arm(CELL.robot)
    place = at(427.0, 265.0)
    across, radial = at(427.0, 205.0), at(427.0 - 300.0, 265.0)
    d1, d2 = math.dist(place, across), math.dist(place, radial)
    assert abs(d1 - d2) < 130
    assert abs(arm.move_time(place, across, 100.0) - arm.move_time(place, radial, 100.0)) > 0.02
    with pytest.raises(TypeError):
        arm.arch_time(300.0, 100.0)
    with pytest.raises(ValueError, match="elbow"):
        ScaraModel(CELL.robot, ScaraSpec(elbow="up"))


# ---------------------------------------------------------------- the bounds


def pricing() -> Pricing:
    sc, cell = load_scenario(ROOT / "scenarios" / "lenses.yaml")
    return Pricing.of(world_arm(cell.robot), cell, sc)


def _belt_log(seconds: float) -> PassLog:
    """A pass log of a belt running at 200 mm/s for ``seconds``, sampled every 20 ms."""
    log = PassLog(0.0, 0.0)
    t = 0.0
    while t < seconds:
        t += 0.02
        log.sample(t, 200.0 * t)
    return log


def test_the_mean_bound_by_hand():
    p = pricing()
    place = p.places["lens"]
    picks = [(1.0, 1100.0, 100.0, "lens"), (2.0, 1000.0, 400.0, "lens")]
    cycles = [2 * p.model.move_time(place, (x, y), 100.0) + p.fixed_s for _, x, y, _ in picks]
    cycle, ppm = mean_bound(p, picks)
    assert cycle == pytest.approx(sum(cycles) / 2) and ppm == pytest.approx(60 / cycle)
    assert mean_bound(p, []) is None


def test_the_replay_takes_what_passes_nearest_first():
    """A belt at 200 mm/s; three parts land together at 1 s: two the robot can take, one
    it cannot (lying wrong). The replay takes both, the cheaper first; a part that lands
    after the end is not taken."""
    p = pricing()
    log = _belt_log(30.0)
    base = 200.0 * 1.0
    log.landed(1, 1.0, 30.0 - base, 500.0, "lens", True)      # far side: dearer
    log.landed(2, 1.0, 30.0 - base, 60.0, "lens", True)       # near the place pose
    log.landed(3, 1.0, 40.0 - base, 300.0, "lens", False)
    log.landed(4, 29.9, 30.0 - 200.0 * 29.9, 300.0, "lens", True)
    assert selection_bound(p, log, (1370.0, -150.0), 30.0) == 2
    # with the far part alone, one; with none usable, none
    log.usable[1] = False
    assert selection_bound(p, log, (1370.0, -150.0), 30.0) == 1
    log.usable[0] = False
    assert selection_bound(p, log, (1370.0, -150.0), 30.0) == 0


def test_a_part_the_replay_placed_comes_back_only_where_placed_parts_do():
    """A part the run left to recirculate lands again as a new pass. Where placed parts
    leave the cell, the replay that took it on its first pass is not offered it again (it
    once placed 61 of 60 parts), nor, if the run dropped it beside itself, its pass then
    under way; in the closed loop the later pass stands in for the replay's own part
    coming back, and is taken."""
    p = pricing()
    log = _belt_log(60.0)
    log.landed(1, 1.0, 30.0 - 200.0, 60.0, "lens", True)
    log.landed(1, 31.0, 30.0 - 200.0 * 31.0, 60.0, "lens", True)   # recirculated
    assert selection_bound(p, log, (1370.0, -150.0), 60.0, placed_leave=True) == 1
    assert selection_bound(p, log, (1370.0, -150.0), 60.0) == 2
    log.landed(2, 40.0, 30.0 - 200.0 * 40.0, 300.0, "lens", True)
    log.landed(2, 40.0, 60.0 - 200.0 * 40.0, 320.0, "lens", True)   # dropped beside it
    assert selection_bound(p, log, (1370.0, -150.0), 60.0, placed_leave=True) == 2
    log.pid[3] = 3                                 # two parts side by side: both taken
    assert selection_bound(p, log, (1370.0, -150.0), 60.0, placed_leave=True) == 3


@pytest.fixture(scope="module")
def runs() -> dict[float, dict]:
    """Lenses, two simulated minutes, with the Cobra 600 and with an arm half as fast."""
    return {f: run_job(_run(f)) for f in (1.0, 0.5)}


def _run(f: float) -> RunOptions:
    """Lenses on the simulated cell with its arm ``f`` times a Cobra 600's speed."""
    d = Path(tempfile.mkdtemp(prefix="scara"))
    (d / "cell.yaml").write_text((ROOT / "cells" / "sim.yaml").read_text().replace(
        "  grip_tolerance_mm: 4.0", f"  grip_tolerance_mm: 4.0\n  sim_speed_factor: {f}"))
    text = (ROOT / "scenarios" / "lenses.yaml").read_text()
    (d / "lenses.yaml").write_text(text.replace("cell: ../cells/sim.yaml", "cell: cell.yaml"))
    return RunOptions(scenario=str(d / "lenses.yaml"), duration=120.0, fast=True, seed=1,
                      view="none")


def test_the_bounds_are_ordered(runs):
    """selection <= corner, mean <= corner, and the run itself under the selection
    yardstick (the replay never waits for vision and never misses a grip); the ceiling is
    the lowest true bound only: a yardstick that moves with the run is never it, and the
    run is put against it as a ratio."""
    r = runs[1.0]
    assert r["robot_bound_kind"] == "corner"
    assert r["robot_bound_mean_ppm"] < r["robot_bound_ppm"]
    assert r["robot_bound_selection_ppm"] < r["robot_bound_ppm"]
    assert 0 < r["parts_per_minute"] <= r["robot_bound_selection_ppm"]
    assert r["ceiling"] in ("robot", "supply", "inflow")
    assert r["of_selection"] == round(r["parts_per_minute"] / r["robot_bound_selection_ppm"], 3)
    assert r["parts_per_minute"] <= r["ceiling_ppm"]
    text = summary(r)
    assert "yardsticks, not bounds:" in text and "selection bound" not in text


def test_the_learners_residual_is_reported(runs):
    r = runs[1.0]
    res = r["robot_model"]["fitted"]["residual"]
    assert res["moves"] == r["robot_model"]["samples"] > 50
    assert res["rms_ms"] > 2.0 and res["max_ms"] >= res["rms_ms"] and res["rms_pct"] > 0.5
    line = next(s for s in summary(r).splitlines() if s.startswith("  robot fit:"))
    assert f"residual rms {res['rms_ms']:.0f} ms ({res['rms_pct']:.1f} %)" in line
    assert len(line) <= 80


def test_a_broken_world_is_seen_in_the_bounds(runs):
    """An arm half as fast as the cell says (``sim_speed_factor: 0.5``): the corner and
    mean bounds price it as it is, every move twice as long."""
    ok, slow = runs[1.0], runs[0.5]
    fixed = ok["robot_bound_cycle_s"] - 2 * _corner_move(ok)
    assert slow["robot_bound_cycle_s"] == pytest.approx(
        fixed + 2 * 2 * _corner_move(ok), rel=1e-3)
    assert slow["robot_bound_ppm"] < 0.7 * ok["robot_bound_ppm"]
    assert slow["robot_bound_mean_ppm"] < 0.75 * ok["robot_bound_mean_ppm"]
    assert slow["robot_bound_selection_ppm"] < ok["robot_bound_selection_ppm"]
    assert slow["parts_per_minute"] <= slow["robot_bound_selection_ppm"]


def _corner_move(r: dict) -> float:
    """One move of the corner cycle (place pose to the best pick point) at factor 1."""
    p = pricing()
    best = p.model.best_pick_point(p.places["lens"], (0.0, p.x_hi, 28.0, 610.0 - 28.0))
    return p.model.move_time(p.places["lens"], best, 100.0)


ARM = """
.PROGRAM main()
    SPEED 50 ALWAYS
    SET f = INVERSE(TRANS(1370, 305, 0, 0, 0, 0))
    SET a = f:TRANS(1370, -150, 0, 0, 180, 0)
    SET b = f:TRANS(1100, 100, 0, 0, 180, 0)
    SET c = f:TRANS(1000, 400, 0, 0, 180, 0)
    MOVE a
    BREAK
    t0 = TIMER(-3)
    MOVE b
    BREAK
    t1 = TIMER(-3)
    MOVE c
    MOVE a
    BREAK
    t2 = TIMER(-3)
.END
"""


def test_the_v_plus_emulators_arm_moves_like_the_scara():
    """The V+ emulator's arm times each motion with the world's SCARA (joint-interpolated,
    at SPEED 50), and two motions in continuous path overlap one's deceleration with the
    next one's acceleration (no per-move noise here)."""
    from tests.support.vplus_rig import make_runtime, run

    rt = make_runtime(ARM)
    world = rt.plant.world
    world.imperfect.time_factor = lambda: 1.0
    run(ARM, rt=rt)
    g = {k: rt.globals[k].v for k in ("t0", "t1", "t2")}
    arm = world.robot_model
    a, b, c = (0.0, -455.0, 0.0), (-270.0, -205.0, 0.0), (-370.0, 95.0, 0.0)
    t_ab, _ = arm.segment_time(a, b, 50.0)
    t_bc, r_bc = arm.segment_time(b, c, 50.0)
    t_ca, r_ca = arm.segment_time(c, a, 50.0)
    assert g["t1"] - g["t0"] == pytest.approx(t_ab, abs=0.02)     # the servo's tick
    assert g["t2"] - g["t1"] == pytest.approx(t_bc + t_ca - min(r_bc, r_ca), abs=0.02)
    # not the Cartesian trapezoid the controller prices with
    cart = RobotModel(CELL.robot).arch_time(math.dist(a, b) - CELL.robot.approach_mm, 50.0)
    assert abs(cart - t_ab) > 0.05
