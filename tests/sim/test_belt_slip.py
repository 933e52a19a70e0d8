"""Belt physics that charge for control: parts slide on the belt when it speeds
up or brakes harder than friction carries them, and clumping rises with the belt's loading
where parts land. Seeded, on virtual time; the slides are checked against hand sums."""

from __future__ import annotations

import dataclasses
import os

import numpy as np
import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config import load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.model import SimImperfections
from feeder_bt.sim.devices import SimConveyor
from feeder_bt.sim.imperfect import Imperfections
from feeder_bt.sim.slip import G_MM_S2, slide
from feeder_bt.sim.world import World

MU_S, MU_K = 0.3, 0.2


@pytest.fixture(scope="module")
def lenses():
    return load_scenario("scenarios/lenses.yaml")


def world_of(lenses, seed: int = 3, **sim) -> tuple[World, SimClock]:
    scenario, cell = lenses
    cell = dataclasses.replace(cell, sim=dataclasses.replace(cell.sim, **sim))
    clock = SimClock()
    return World(scenario, cell, clock, seed), clock


def run_to(world: World, clock: SimClock, until: float, dt: float = 0.05) -> None:
    t = clock.now()
    while t < until - 1e-9:
        t = min(until, t + dt)
        clock.advance_to(t)
        world.step(t)


def fill(w: World, clock: SimClock, speed: float, until: float = 20.0,
         stop_belt: bool = False) -> None:
    """Lift parts onto the belt running at ``speed`` until ``until``, then stop the incline
    (and the belt, with ``stop_belt``) and let them come to rest for a second."""
    w.horizontal.jog(0.0, speed)
    w.incline.jog(0.0, 100.0)
    run_to(w, clock, until)
    w.incline.jog(clock.now(), 0.0)
    if stop_belt:
        w.horizontal.jog(clock.now(), 0.0)
    run_to(w, clock, until + 1.0)


def loaded_belt(lenses, speed: float = 300.0, **sim) -> tuple[World, SimClock]:
    """A world with a dozen or so lenses at rest on a belt running at ``speed``."""
    w, clock = world_of(lenses, belt_mu_static=MU_S, belt_mu_kinetic=MU_K, **sim)
    fill(w, clock, speed)
    assert len(w.on_horizontal) >= 5 and w.counts["slips"] == 0
    return w, clock


def offsets(w: World) -> dict[int, float]:
    """Each part's place along the belt, in the belt's own frame."""
    return {p.id: p.x0 for p in w.on_horizontal.values()}


# ------------------------------------------------------------------ the sliding law


def test_slide_is_exact_per_segment():
    mus, muk = np.full(4, MU_S * G_MM_S2), np.full(4, MU_K * G_MM_S2)
    a_hard, a_soft = 1.5 * MU_S * G_MM_S2, 0.9 * MU_S * G_MM_S2
    # at rest relative to the belt: a gentle push moves nothing, a hard one slides back
    u, dx = slide(np.zeros(4), a_soft, 0.2, mus, muk)
    assert not u.any() and not dx.any()
    u, dx = slide(np.zeros(4), a_hard, 0.2, mus, muk)
    rel = a_hard - MU_K * G_MM_S2                     # the belt outruns the part by this
    assert u == pytest.approx(np.full(4, -rel * 0.2))
    assert dx == pytest.approx(np.full(4, -0.5 * rel * 0.2 ** 2))
    # a part 50 mm/s behind a belt at constant speed catches up in 50 / (mu_k g) s,
    # covering half of 50 mm/s times that, then sticks
    u, dx = slide(np.array([-50.0, 0.0, 50.0, -5.0]), 0.0, 1.0, mus, muk)
    t_catch = 50.0 / (MU_K * G_MM_S2)
    assert u.tolist() == [0.0, 0.0, 0.0, 0.0]
    assert dx[:3] == pytest.approx([-25.0 * t_catch, 0.0, 25.0 * t_catch])
    # split in two, the same answer: the law has no step size
    u1, d1 = slide(np.array([-50.0]), 0.0, 0.001, mus[:1], muk[:1])
    u2, d2 = slide(u1, 0.0, 0.999, mus[:1], muk[:1])
    assert d1 + d2 == pytest.approx(dx[:1])


def test_a_hard_brake_slides_parts_by_the_hand_distance(lenses):
    v, a = 300.0, 5000.0                              # 0.51 g against mu_s g = 0.3 g
    assert a > MU_S * G_MM_S2
    for dt in (0.05, 0.013):                          # any stepping: the same slide
        w, clock = loaded_belt(lenses, v)
        before = offsets(w)
        w.horizontal.accel = a
        w.horizontal.jog(clock.now(), 0.0)
        run_to(w, clock, 24.0, dt)
        # the part brakes at mu_k g the whole way (v^2 / (2 mu_k g)), the belt at a
        expect = v * v / (2 * MU_K * G_MM_S2) - v * v / (2 * a)
        assert expect == pytest.approx(13.94, abs=0.01)
        moved = [p.x0 - before[p.id] for p in w.on_horizontal.values()]
        assert moved == pytest.approx([expect] * len(moved), abs=1e-6)
        assert w.counts["slips"] == len(moved)
        assert all(p.slip_v == 0.0 for p in w.on_horizontal.values())   # stuck again
        assert w.lost() == 0


def test_a_hard_start_slides_parts_back(lenses):
    w, clock = loaded_belt(lenses, 300.0)
    w.horizontal.jog(clock.now(), 0.0)                # a gentle stop: nothing slides
    run_to(w, clock, 22.0)
    before = offsets(w)
    assert w.counts["slips"] == 0
    v, a = 200.0, 4000.0
    w.horizontal.accel = a
    w.horizontal.jog(clock.now(), v)
    run_to(w, clock, 23.0)
    expect = -(v * v / (2 * MU_K * G_MM_S2) - v * v / (2 * a))
    moved = [p.x0 - before[p.id] for p in w.on_horizontal.values() if p.id in before]
    assert moved == pytest.approx([expect] * len(moved), abs=1e-6)


def test_braking_within_static_friction_slides_nothing(lenses):
    w, clock = loaded_belt(lenses, 300.0)
    before = offsets(w)
    w.horizontal.accel = 0.95 * MU_S * G_MM_S2        # just under what friction holds
    w.horizontal.jog(clock.now(), 0.0)
    run_to(w, clock, 24.0)
    assert offsets(w) == before and w.counts["slips"] == 0 and w.slid_mm == 0.0


def test_slip_off_when_ideal_or_zero(lenses):
    for sim in ({"ideal": True}, {"belt_mu_static": 0.0}):
        w, clock = world_of(lenses, **sim)
        fill(w, clock, 300.0)
        before = offsets(w)
        w.horizontal.accel = 50_000.0
        w.horizontal.jog(clock.now(), 0.0)
        run_to(w, clock, 23.0)
        assert offsets(w) == before and w.counts["slips"] == 0


def test_a_shake_moves_parts_on_the_belt(lenses):
    """A shake (jam recovery: 20 mm back and forth at full speed) at the cell's 1500 mm/s2:
    parts on a slippery belt (mu_s g = 0.1 g, under 0.15 g) slide on it; on the default
    belt (0.30, docs/simulator.md) they ride with it."""
    moved = {}
    for mu_s, mu_k in ((0.1, 0.08), (SimImperfections.belt_mu_static,
                                     SimImperfections.belt_mu_kinetic)):
        w, clock = world_of(lenses, belt_mu_static=mu_s, belt_mu_kinetic=mu_k)
        fill(w, clock, 100.0, stop_belt=True)
        before = offsets(w)
        assert before
        SimConveyor("horizontal", w.horizontal, w).shake(20.0, 3)
        run_to(w, clock, 25.0)
        moved[mu_s] = max(abs(p.x0 - before[p.id]) for p in w.on_horizontal.values())
        assert all(p.slip_v == 0.0 for p in w.on_horizontal.values())
        assert w.lost() == 0
    assert moved[0.1] > 2.0
    assert moved[SimImperfections.belt_mu_static] == 0.0


# ------------------------------------------------------------------ clumping and loading


def test_clump_probability_rises_with_cover():
    spec = SimImperfections(clump_prob=0.05, clump_cover_scale=0.5)   # not the defaults
    imp = Imperfections(spec, 20.0, 4.0, seed=1)
    ps = [imp.clump_probability(c) for c in (0.0, 0.05, 0.2, 0.5, 1.0)]
    assert ps[0] == 0.05 and all(b > a for a, b in zip(ps, ps[1:], strict=False))
    assert ps[3] == pytest.approx(0.05 + 0.95 * (1 - np.exp(-1.0)))
    flat = Imperfections(dataclasses.replace(spec, clump_cover_scale=0.0), 20.0, 4.0, 1)
    assert flat.clump_probability(0.9) == 0.05
    ideal = Imperfections(dataclasses.replace(spec, ideal=True), 20.0, 4.0, 1)
    assert ideal.clump_probability(0.9) == 0.0


def clumped_share(lenses, h_speed: float, **sim) -> tuple[float, int, World]:
    w, clock = world_of(lenses, seed=11, **sim)
    w.horizontal.jog(0.0, h_speed)
    w.incline.jog(0.0, 150.0)
    run_to(w, clock, 120.0)
    assert w.lost() == 0
    return w.counts["landed_clumped"] / w.counts["landed"], w.counts["landed"], w


def test_clumping_rises_with_loading(lenses):
    """The same lift feeding a slow belt (parts pile where they land) and a fast one:
    more clumped landings on the slow belt; without the loading term, about as many."""
    slow, n_slow, ws = clumped_share(lenses, 40.0)
    fast, n_fast, wf = clumped_share(lenses, 300.0)
    assert n_slow > 100 and n_fast > 100
    assert ws.zone_cover(ws.t) > wf.zone_cover(wf.t)
    assert slow > fast + 0.05
    assert fast > 0.02                                # a fast belt still clumps a little
    slow0, _, _ = clumped_share(lenses, 40.0, clump_cover_scale=0.0)
    fast0, _, _ = clumped_share(lenses, 300.0, clump_cover_scale=0.0)
    assert abs(slow0 - fast0) < 0.02 and slow > slow0 + 0.1 and fast > fast0


# ------------------------------------------------------------------ a whole run


def test_nothing_lost_with_slip_and_loading_clumps(tmp_path):
    """Ten minutes of lenses on a slippery belt (every speed change of the adjuster slides
    the parts: 1500 mm/s2 against mu_s g = 0.1 g) with clumping rising with loading:
    parts slide, clump, are missed; none is lost or duplicated."""
    cell = tmp_path / "cell.yaml"
    cell.write_text(open("cells/sim.yaml").read()
                    + "\nsim: {belt_mu_static: 0.1, belt_mu_kinetic: 0.08}\n")
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", cell=str(cell), fast=True,
                           duration=600.0, seed=2, view="none", db=None))
    p, world = r["parts"], r["world"]
    assert p["lost"] == 0 and p["duplicated"] == 0
    assert world["slips"] > 0 and world["slid_mm"] > 0
    assert world["landed_clumped"] > 0
    assert sum(p["retrieved"].values()) > 300


def test_kinetic_friction_above_static_is_refused(tmp_path):
    from feeder_bt.config import load_cell
    from feeder_bt.core.errors import ConfigError
    f = tmp_path / "c.yaml"
    f.write_text(open("cells/sim.yaml").read()
                 + "\nsim: {belt_mu_static: 0.2, belt_mu_kinetic: 0.3}\n")
    with pytest.raises(ConfigError, match=r"sim.belt_mu_kinetic: must be <= sim.belt_mu_static"):
        load_cell(f)
    f.write_text(open("cells/sim.yaml").read() + "\nsim: {belt_mu_static: 3}\n")
    with pytest.raises(ConfigError, match=r"sim.belt_mu_static"):
        load_cell(f)
    f.write_text(open("cells/sim.yaml").read() + "\nsim: {belt_mu_static: 0}\n")
    assert load_cell(f).sim.belt_mu_static == 0.0      # slip off, whatever the kinetic
    f.write_text(open("cells/sim.yaml").read() + "\nsim: {belt_mu_kinetic: 0}\n")
    with pytest.raises(ConfigError, match=r"sim.belt_mu_kinetic: must be > 0"):
        load_cell(f)


def test_friction_per_part_type():
    """lenses_and_squares with the squares on a slicker footing (mu_s 0.1, its own) and the
    lenses on the cell's (0.3): braking at 2000 mm/s2 (0.2 g) slides the squares only."""
    scenario, cell = load_scenario("scenarios/lenses_and_squares.yaml")
    sq = dataclasses.replace(scenario.parts["square"], belt_mu_static=0.1, belt_mu_kinetic=0.08)
    scenario = dataclasses.replace(scenario, parts={**scenario.parts, "square": sq})
    cell = dataclasses.replace(cell, sim=dataclasses.replace(
        cell.sim, belt_mu_static=MU_S, belt_mu_kinetic=MU_K))
    clock = SimClock()
    w = World(scenario, cell, clock, 4)
    fill(w, clock, 200.0, until=25.0)
    before = offsets(w)
    types = {p.type for p in w.on_horizontal.values()}
    assert types == {"lens", "square"}
    w.horizontal.accel = 2000.0
    w.horizontal.jog(clock.now(), 0.0)
    run_to(w, clock, 28.0)
    v, a = 200.0, 2000.0
    for p in w.on_horizontal.values():
        moved = p.x0 - before[p.id]
        if p.type == "square":
            assert moved == pytest.approx(v * v / (2 * 0.08 * G_MM_S2) - v * v / (2 * a))
        else:
            assert moved == 0.0


def test_a_parts_kinetic_friction_above_its_static_is_refused(tmp_path):
    from feeder_bt.core.errors import ConfigError
    text = open("scenarios/lenses.yaml").read().replace(
        "cell: ../cells/sim.yaml", f"cell: {os.path.abspath('cells/sim.yaml')}")
    text = text.replace("    tool_offset: [0, 0, 0]\n",
                        "    tool_offset: [0, 0, 0]\n    belt_mu_kinetic: 0.5\n", 1)
    f = tmp_path / "s.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=r"s.yaml:\d+: parts.lens.belt_mu_kinetic: 0.5 is above"):
        load_scenario(f)


def test_a_part_sliding_back_stops_at_the_belts_start(lenses):
    """A very hard start on a slick belt: parts near the ramp slide back to the belt's
    start and no further (the ramp's foot), then ride on; nothing lost."""
    w, clock = world_of(lenses, belt_mu_static=0.05, belt_mu_kinetic=0.02)
    w.incline.jog(0.0, 100.0)
    run_to(w, clock, 20.0)                  # the belt stands: parts lie where they land
    w.incline.jog(clock.now(), 0.0)
    run_to(w, clock, 21.0)
    assert w.on_horizontal
    w.horizontal.accel = 8000.0
    w.horizontal.jog(clock.now(), 400.0)
    for _ in range(40):
        run_to(w, clock, clock.now() + 0.025)
        belt = w.horizontal.pos(clock.now())
        assert min(p.x0 + belt for p in w.on_horizontal.values()) >= -1e-9
    assert w.counts["slips"] > 0 and w.lost() == 0
