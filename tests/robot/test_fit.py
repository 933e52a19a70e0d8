"""Policies that learn the robot: the pick policies price with a robot model
fitted online from measured move times, which converges to the simulated arm's truth when
that arm is slower or faster than the cell description says."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from feeder_bt.analysis.report import robot_bound
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.behaviours.policies import ShortestCycle
from feeder_bt.config import load_cell, load_scenario
from feeder_bt.hal.interfaces import Pose
from feeder_bt.robot.fit import K_BOUNDS, RobotFit, Timing, pricing_model, robot_fit
from feeder_bt.robot.model import RobotModel, with_speed_factor
from feeder_bt.robot.scara import world_arm
from tests.support.treeutil import make_ctx, part

ROOT = Path(__file__).resolve().parents[2]
CELL = load_cell(ROOT / "cells" / "sim.yaml")


def synthetic(fit: RobotFit, factor: float, n: int, seed: int = 3) -> None:
    """``n`` moves of an arm ``factor`` times as fast as described, seen at a 200 Hz tick,
    one in ten a time-out (2 s late) that must not count."""
    truth = RobotModel(with_speed_factor(CELL.robot, factor))
    rng = np.random.default_rng(seed)
    for i in range(n):
        d = float(rng.uniform(50.0, 900.0))
        t = truth.arch_time(d, 100.0) + float(rng.uniform(0.0, 0.005))
        if i % 10 == 9:
            t += 2.0
        fit.observe("place", d, 100.0, t)


@pytest.mark.parametrize("factor", [0.8, 1.25])
def test_the_fit_converges_on_a_slower_or_faster_arm(factor):
    fit = RobotFit(CELL.robot)
    synthetic(fit, factor, 200)
    assert fit.k == pytest.approx(1.0 / factor, rel=0.03)
    assert abs(fit.c) < 0.01
    assert fit.rejected["implausible"] == 20          # every time-out, and nothing else
    s = fit.summary()
    assert s["fitted"]["v_max_mm_s"] == pytest.approx(CELL.robot.v_max_mm_s * factor, rel=0.04)
    assert s["nominal"]["v_max_mm_s"] == CELL.robot.v_max_mm_s and s["samples"] == 180


def test_the_fit_stays_within_its_bounds():
    fit = RobotFit(CELL.robot)
    nominal = RobotModel(CELL.robot)
    for d in np.linspace(50.0, 900.0, 300):     # every move at the slowest plausible time
        fit.observe("pick", float(d), 100.0, K_BOUNDS[1] * nominal.arch_time(float(d), 100.0))
    assert K_BOUNDS[0] <= fit.k <= K_BOUNDS[1]
    assert not fit.rejected


def test_a_pick_that_may_have_waited_for_its_part_is_not_a_move():
    fit = RobotFit(CELL.robot)
    fit.pick_done(Timing("pick", 0.0, (1330.0, -120.0), 100.0, usable=False), 3.0, 900.0)
    assert fit.rejected["may_have_waited"] == 1 and not fit.samples and fit.k == 1.0


def test_pick_choices_follow_the_fitted_robot():
    """A part in reach now but far from the arm (A), against one still upstream that the
    arm waits for (B): B costs a wait, which no arm speed shortens, and one move; A two
    moves. With the nominal arm A is quicker; once the fit has learnt that the arm is 25 %
    slower, B is."""
    ctx = make_ctx(retrieve={"policy": "shortest_cycle"})
    ctx.hal.robot_position.at = Pose(1330.0, -120.0)
    pol = ShortestCycle(ctx)
    pol.belt_mm_s = 150.0
    a, b = part(1000.0, 520.0), part(740.0, 100.0)
    assert pol.choose([a, b], lambda q: q.x_mm) is a
    synthetic(robot_fit(ctx), 0.8, 200)
    assert robot_fit(ctx).k == pytest.approx(1.25, rel=0.03)
    assert pol.choose([a, b], lambda q: q.x_mm) is b


def test_learning_off_prices_with_the_nominal_model():
    ctx = make_ctx(retrieve={"policy": "shortest_cycle", "learn_robot": False})
    assert pricing_model(ctx) is robot_fit(ctx).nominal
    ctx = make_ctx(retrieve={"policy": "shortest_cycle"})
    assert pricing_model(ctx) is robot_fit(ctx).model


def _learnt(tmp_path: Path, factor: float) -> tuple[dict, float]:
    """A simulated minute of lenses with the arm ``factor`` times as fast as a Cobra 600
    (the trees see the cell's description): the fitted model, and the world's true
    corner bound."""
    cell = (ROOT / "cells" / "sim.yaml").read_text().replace(
        "  grip_tolerance_mm: 4.0", f"  grip_tolerance_mm: 4.0\n  sim_speed_factor: {factor}")
    d = tmp_path / f"f{factor}"
    d.mkdir()
    (d / "cell.yaml").write_text(cell)
    text = (ROOT / "scenarios" / "lenses.yaml").read_text()
    text = re.sub(r"^(  policy:) *\S+", r"\1 shortest_cycle", text, flags=re.M)
    scen = d / "lenses.yaml"
    scen.write_text(text.replace("cell: ../cells/sim.yaml", "cell: cell.yaml"))
    r = run_job(RunOptions(scenario=str(scen), duration=60.0, fast=True, seed=2, view="none"))
    sc, cl = load_scenario(scen)
    return r["robot_model"], robot_bound(cl, sc, world_arm(cl.robot, factor))[1]


@pytest.mark.parametrize("factor", [0.8, 1.25])
def test_a_simulated_run_learns_the_arm(tmp_path, factor):
    """The simulated arm (a SCARA, feeder_bt.robot.scara) moves ``factor`` times as fast as the
    cell's; the learner fits its Cartesian model to it. The world is no longer of the
    model's form, so the fit is compared with the same run at factor 1: after
    a simulated minute the time scale follows the arm within 6 %, and the fitted corner
    bound is within 10 % of the world's (the fit extrapolates to the corner from where
    parts were picked)."""
    base, _ = _learnt(tmp_path, 1.0)
    m, true_bound = _learnt(tmp_path, factor)
    assert m["sim_speed_factor"] == factor and m["learning"] is True
    assert m["picks"] >= 20 and m["places"] >= 30
    ratio = m["fitted"]["time_scale"] / base["fitted"]["time_scale"]
    assert ratio == pytest.approx(1.0 / factor, rel=0.06)
    assert m["fitted"]["v_max_mm_s"] / base["fitted"]["v_max_mm_s"] == pytest.approx(
        factor, rel=0.06)
    assert m["nominal"]["time_scale"] == 1.0
    assert m["fitted"]["robot_bound_ppm"] == pytest.approx(true_bound, rel=0.10)
    # the world is not the model's form: the fit leaves a residual, and it is reported
    assert m["fitted"]["residual"]["rms_ms"] > 2.0


def test_the_simulated_arm_is_slower_only_in_the_world():
    slow = dataclasses.replace(CELL.robot, sim_speed_factor=0.8)
    assert RobotModel(slow).arch_time(305.0, 100.0) == RobotModel(CELL.robot).arch_time(305.0, 100.0)
    true = RobotModel(with_speed_factor(slow, slow.sim_speed_factor))
    assert true.arch_time(305.0, 100.0) == pytest.approx(
        RobotModel(CELL.robot).arch_time(305.0, 100.0) / 0.8)
    # the world's arm (a SCARA) is slowed the same way: every move 1/0.8 as long
    assert world_arm(slow, 0.8).standard_cycle() == pytest.approx(
        world_arm(slow).standard_cycle() / 0.8)
