"""The simulated cell's imperfections: each is there by default, each can make
something fail, and ``sim: {ideal: true}`` turns them off. Seeded and on virtual time."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from feeder_bt.config import load_cell, load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import ConfigError, MissedGrab
from feeder_bt.core.geometry import place_outline, pose_outline
from feeder_bt.core.model import SimImperfections
from feeder_bt.hal.interfaces import PickTarget, Pose
from feeder_bt.sim.devices import make_sim_hal
from feeder_bt.sim.imperfect import Imperfections, true_calibration
from feeder_bt.sim.render import Renderer
from feeder_bt.sim.world import World
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.pixels import Calibration


@pytest.fixture(scope="module")
def lenses():
    return load_scenario("scenarios/lenses.yaml")


def world_of(lenses, seed: int = 7, **sim) -> tuple[World, SimClock]:
    scenario, cell = lenses
    cell = dataclasses.replace(cell, sim=dataclasses.replace(cell.sim, **sim))
    clock = SimClock()
    return World(scenario, cell, clock, seed), clock


def run_belts(world: World, clock: SimClock, seconds: float, dt: float = 0.05,
              h: float = 150.0, i: float = 60.0) -> None:
    world.horizontal.jog(clock.now(), h)
    world.incline.jog(clock.now(), i)
    t = clock.now()
    end = t + seconds
    while t < end - 1e-9:
        t = min(end, t + dt)
        clock.advance_to(t)
        world.step(t)


# ------------------------------------------------------------------ the cell description


def test_on_by_default_and_off_with_ideal(tmp_path):
    cell = load_cell("cells/sim.yaml")
    assert not cell.sim.ideal and cell.sim.encoder_noise_counts > 0
    assert true_calibration(cell) != cell.camera.calibration
    f = tmp_path / "c.yaml"
    f.write_text(open("cells/sim.yaml").read() + "\nsim: {ideal: true}\n")
    ideal = load_cell(f)
    assert ideal.sim.ideal and true_calibration(ideal) == ideal.camera.calibration
    f.write_text(open("cells/sim.yaml").read() + "\nsim: {clump_prob: 1.5}\n")
    with pytest.raises(ConfigError, match="sim.clump_prob"):
        load_cell(f)


# ------------------------------------------------------------------ encoders


def test_encoder_counts_are_quantised_noisy_and_scaled(lenses):
    w, clock = world_of(lenses)
    w.horizontal.jog(0.0, 200.0)
    times = np.arange(1.0, 3.0, 0.0137)
    exact = [w.horizontal.pos(t) * w.cpm for t in times]      # the cell's counts/mm
    galil = [w.galil_count(t) for t in times]
    assert all(isinstance(c, int) for c in galil)
    # the true counts per mm are 0.1 % more than the cell's belt calibration says
    ratio = np.polyfit(exact, galil, 1)[0]
    assert ratio == pytest.approx(1.0 + w.cell.sim.encoder_scale_pct / 100.0, abs=5e-5)
    resid = np.array(galil) - np.array([w.horizontal.pos(t) * w.imperfect.true_cpm
                                        for t in times])
    assert 0.3 < resid.std() < 1.0                # 0.5 counts of noise plus rounding
    assert w.galil_count(1.5) == w.galil_count(1.5)           # a function of time, not of reads
    # the robot's channel is sampled once a trajectory cycle (16 ms) and held
    t0 = 2.0 + 0.0001
    assert w.cell.sim.robot_sample_s == 0.016
    assert w.robot_count(t0) == w.robot_count(t0 + 0.015)
    assert w.robot_count(t0 + 0.0161) - w.robot_count(t0) >= 50  # 0.2 mm/ms: 64 counts

    ideal, _ = world_of(lenses, ideal=True)
    ideal.horizontal.jog(0.0, 200.0)
    assert [ideal.galil_count(t) for t in times] == [round(e) for e in exact]


# ------------------------------------------------------------------ camera calibration


def test_calibration_residual_is_a_measurable_pick_error(lenses):
    """A lens rendered through the world's true mapping and located with the cell's own
    calibration is found off its true centre by what the residual predicts."""
    scenario, cell = lenses
    hal = make_sim_hal(scenario, cell, SimClock(), 1)
    try:
        assert hal.camera.calibration.spec == cell.camera.calibration   # no truth leaks
    finally:
        hal.close()
    cal = Calibration(cell.camera.calibration)
    part = scenario.parts["lens"]
    pose = next(p for p, s in part.poses.items() if s.pickable)
    errors = {}
    for name, truth in (("real", true_calibration(cell)), ("ideal", cell.camera.calibration)):
        renderer = Renderer(cell.camera, truth=truth)
        locator = Locator(scenario.vision, scenario.parts, cal)
        rng = np.random.default_rng(3)
        locator.set_golden(renderer.golden(rng))
        errs = []
        for x, y in ((150.0, 120.0), (400.0, 500.0), (300.0, 300.0)):
            outline = place_outline(pose_outline(part, pose), x, y, 0.0)
            (det,) = locator.locate(renderer.render([outline], rng)).parts
            predicted = cal.px_to_mm(Calibration(truth).mm_to_px([[x, y]]))[0]
            assert math.hypot(det.x_mm - predicted[0], det.y_mm - predicted[1]) < 0.25
            errs.append(math.hypot(det.x_mm - x, det.y_mm - y))
        errors[name] = max(errs)
    assert errors["real"] > 0.3 > errors["ideal"]
    assert errors["real"] < 1.5                   # a residual, not a mis-calibration


# ------------------------------------------------------------------ landing


def test_a_dropped_part_slides_and_settles(lenses):
    w, clock = world_of(lenses, seed=11)
    run_belts(w, clock, 60.0)
    t = clock.now()
    row = next(r for r in w.truth(t) if r["pickable"] and r["singulated"])
    target = PickTarget(row["id"], row["x_mm"], row["y_mm"], row["angle_deg"],
                        w.robot_count(t))
    w.grip(target, t)
    w.robot_pose = Pose(900.0, 300.0)
    w.drop_held(t)
    part = w.parts[row["id"]]

    def rel(at: float) -> tuple[float, float]:        # the part's place on the belt
        x, y = w.part_xy(part, at)
        return x - w.horizontal.pos(at), y

    settle = w.cell.sim.settle_s
    start, mid, end, later = rel(t), rel(t + settle / 2), rel(t + settle), rel(t + 5 * settle)
    assert start == pytest.approx((900.0 - w.horizontal.pos(t), 300.0))
    slide = math.hypot(end[0] - start[0], end[1] - start[1])
    assert slide > 0.2                                # it moved on the belt ...
    assert 0.0 < math.hypot(mid[0] - start[0], mid[1] - start[1]) < slide
    assert later == pytest.approx(end)                # ... and came to rest
    assert w.lost() == 0


def test_clumps_land_touching_and_render_as_one_blob(lenses):
    scenario, _ = lenses
    calm, c1 = world_of(lenses, seed=5, clump_prob=0.0, clump_cover_scale=0.0)
    clumpy, c2 = world_of(lenses, seed=5, clump_prob=0.5)
    for w, c in ((calm, c1), (clumpy, c2)):
        run_belts(w, c, 90.0)
    assert clumpy.counts["landed_clumped"] > 10 and calm.counts["landed_clumped"] == 0
    assert clumpy.counts["landed_touching"] > calm.counts["landed_touching"] + 10
    # the camera sees a clump as one blob, which the recipe does not take for a lens
    w, clock = clumpy, c2
    cal = Calibration(w.cell.camera.calibration)
    renderer = Renderer(w.cell.camera, truth=true_calibration(w.cell))
    locator = Locator(scenario.vision, scenario.parts, cal)
    rng = np.random.default_rng(1)
    locator.set_golden(renderer.golden(rng))
    checked = 0
    for _ in range(40):
        run_belts(w, clock, 0.5)
        t = clock.now()
        inside = [r for r in w.truth(t) if 120.0 < r["x_mm"] < 520.0]
        clumped = [r for r in inside if not r["singulated"]]
        if not clumped:
            continue
        result = locator.locate(renderer.render(w.visible_outlines(t, (80.0, 564.0)), rng))
        for r in clumped:
            near = [d for d in result.parts if d.pickable
                    and math.hypot(d.x_mm - r["x_mm"], d.y_mm - r["y_mm"]) < 8.0]
            assert not near, (r, near)
            checked += 1
        assert result.rejected
    assert checked >= 4


# ------------------------------------------------------------------ grip


def test_grip_success_falls_with_the_offset():
    imp = Imperfections(SimImperfections(), cpm=20.0, grip_d50_mm=4.0, seed=3)
    rate = {d: np.mean([imp.grip_holds(d) for _ in range(2000)]) for d in (0.5, 4.0, 5.5)}
    assert rate[0.5] > 0.98 and 0.4 < rate[4.0] < 0.6 and rate[5.5] < 0.1
    p = [imp.grip_probability(d) for d in np.linspace(0.0, 7.0, 30)]
    assert all(a >= b for a, b in zip(p, p[1:], strict=False))
    ideal = Imperfections(SimImperfections(ideal=True), cpm=20.0, grip_d50_mm=4.0, seed=3)
    assert ideal.grip_holds(3.9) and not ideal.grip_holds(4.1)


def test_a_grip_far_off_centre_often_fails_in_the_world(lenses):
    missed = {}
    for dx in (0.0, 4.5):
        fails = 0
        for seed in range(12):
            w, clock = world_of(lenses, seed=seed)
            run_belts(w, clock, 45.0, dt=0.1)
            t = clock.now()
            row = next(r for r in w.truth(t) if r["pickable"] and r["singulated"])
            target = PickTarget(row["id"], row["x_mm"] + dx, row["y_mm"], row["angle_deg"],
                                w.robot_count(t))
            try:
                w.grip(target, t)
            except MissedGrab:
                fails += 1
        missed[dx] = fails
    assert missed[0.0] <= 1 and missed[4.5] >= 4


# ------------------------------------------------------------------ robot


def test_robot_move_times_vary_around_the_nominal_model(lenses):
    def times(**sim) -> list[float]:
        scenario, cell = lenses
        cell = dataclasses.replace(cell, sim=dataclasses.replace(cell.sim, **sim))
        clock = SimClock()
        hal = make_sim_hal(scenario, cell, clock, 2)
        out = []
        try:
            for i in range(30):
                start = clock.now()
                job = hal.robot.move_to(Pose(1300.0, 100.0 + 300.0 * (i % 2)))
                t = start
                while not job.done:
                    t += 0.002
                    clock.advance_to(t)
                    hal.step(t)
                out.append(t - start)
        finally:
            hal.close()
        return out

    real, ideal = np.array(times()[1:]), np.array(times(ideal=True)[1:])
    assert ideal.std() < 0.003                         # steps of 2 ms only
    assert real.std() > 0.003 and abs(real.mean() - ideal.mean()) < 0.02
