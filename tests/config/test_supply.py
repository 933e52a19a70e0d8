"""Supply plans: totes and shipping, mix drift, friction, the operator's speed
override; accounting by identity with parts arriving and leaving; and the supply bound
the controller counts, checked against the simulated world's truth. Seeded, virtual time."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario
from feeder_bt.config.schema import file_kind, schema
from feeder_bt.config.supply import SupplyPlanSpec, Totes, load_supply_plan
from feeder_bt.control.cell import Cell
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import ConfigError, FeederError
from feeder_bt.hal.interfaces import PickTarget, Pose
from feeder_bt.policy.supply_bound import ReachWindow
from feeder_bt.sim.devices import make_sim_hal
from feeder_bt.sim.supply import apply_supply, tote_counts, with_start
from feeder_bt.sim.world import RECYCLE_S, World

ROOT = Path(__file__).resolve().parents[2]
PLANS = sorted((ROOT / "supply").glob("*.yaml"))
RUN_S = 90.0                # the runs' length: the belt is full after about 25 s


@pytest.fixture(scope="module")
def lenses():
    return load_scenario(ROOT / "scenarios/lenses.yaml")


@pytest.fixture(scope="module")
def mixed():
    return load_scenario(ROOT / "scenarios/lenses_and_squares.yaml")


def _hal(scn, plan: SupplyPlanSpec | None = None, seed: int = 3):
    scenario, cell = scn
    clock = SimClock()
    hal = make_sim_hal(with_start(scenario, plan), cell, clock, seed=seed)
    driver = apply_supply(hal, plan) if plan is not None else None
    return hal, clock, driver


def _to(hal, clock, t: float, every=None) -> None:
    while clock.now() < t - 1e-9:
        clock.advance_to(min(t, clock.now() + 0.5))
        hal.step(clock.now())
        if every is not None:
            every(hal.world)


@pytest.fixture(scope="module")
def plain():
    """A plain lenses run (no plan) and the world's truth of its supply when feeding stopped:
    parts gripped, plus pickable parts that rode through the reach to the belt's end, plus
    those past the camera and still to come through the reach; a part counts only if it
    touched no other part since it landed (singulated while the camera saw it: a part whose
    neighbour fell off first is not singulated after the fact). (report, truth count)."""
    seen = {"through": 0, "at_stop": 0}
    touched: set[int] = set()
    scenario, cell = load_scenario(ROOT / "scenarios/lenses.yaml")
    reach = ReachWindow(cell, scenario)
    cam = cell.camera
    x_cam = cam.calibration.origin_mm[0] + cam.height_px * cam.calibration.mm_per_px
    fall, settle, land, stop = World._fall, World._settle, World._land, Cell.stop

    def counts(w: World, pid: int, x: float) -> bool:
        part = w.parts[pid]
        return part.pickable and pid not in touched and reach.crosses(x, part.y)

    def counting_fall(self: World, t: float, pid: int) -> None:
        seen["through"] += counts(self, pid, 0.0)
        fall(self, t, pid)

    def marking_settle(self: World, part, t: float) -> None:
        settle(self, part, t)
        if part.touching:
            touched.add(part.id)
            touched.update(part.touching)

    def new_pass(self: World, t: float) -> None:
        touched.discard(self.on_incline[0])
        land(self, t)

    def stop_and_count(self: Cell) -> None:
        w: World = self.hal.world
        t = w.now()
        coming = sum(counts(w, pid, w.part_xy(p, t)[0]) for pid, p in w.on_horizontal.items()
                     if w.part_xy(p, t)[0] > x_cam)
        seen["at_stop"] = w.counts["gripped"] + seen["through"] + coming
        stop(self)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(World, "_fall", counting_fall)
        mp.setattr(World, "_settle", marking_settle)
        mp.setattr(World, "_land", new_pass)
        mp.setattr(Cell, "stop", stop_and_count)
        r = _run(None, RUN_S)
    return r, seen["at_stop"]


def _plan(tmp_path: Path, text: str, name: str = "p.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _run(plan: str | None, seconds: float, seed: int = 1) -> dict:
    return run_job(RunOptions(scenario=str(ROOT / "scenarios/lenses.yaml"), duration=seconds,
                              fast=True, seed=seed, view="none", supply=plan))


# ---------------------------------------------------------------------------- the files


@pytest.mark.parametrize("path", PLANS, ids=lambda p: p.name)
def test_shipped_plans_load_and_check_as_supply_plans(path, capsys):
    load_supply_plan(path)
    assert file_kind(path) == "supply"
    assert main(["check", str(path)]) == 0
    assert f"ok: {path} (a supply plan)" in capsys.readouterr().out


def test_the_four_kinds_are_shipped():
    assert {p.name for p in PLANS} >= {"batch_refill.yaml", "mix_drift.yaml", "friction.yaml",
                                       "operator_slow.yaml"}


def test_schema_follows_the_loaders_models():
    s = schema("supply")
    assert set(s["properties"]) == {"seed", "start", "ship_placed", "totes", "friction",
                                    "operator"}
    totes = s["properties"]["totes"]["anyOf"][0]
    assert totes["required"] == ["every_s", "parts"]
    assert totes["properties"]["parts"]["minimum"] == 1
    lift = s["properties"]["friction"]["items"]["properties"]["lift"]
    assert (lift["minimum"], lift["maximum"]) == (0, 2)


@pytest.mark.parametrize("path", PLANS, ids=lambda p: p.name)
def test_shipped_plans_are_valid_against_the_schema(path):
    import jsonschema
    import yaml
    s = schema("supply")
    jsonschema.Draft7Validator.check_schema(s)
    data = yaml.safe_load(path.read_text())
    assert list(jsonschema.Draft7Validator(s).iter_errors(data)) == []
    data["totes"] = {"every_s": 60, "parts": 5, "mix": {"lens": -1}, "evry_s": 1}
    found = {e.message for e in jsonschema.Draft7Validator(s).iter_errors(data)}
    assert any("evry_s" in m for m in found) and any("-1" in m for m in found)


@pytest.mark.parametrize("text, where, what", [
    ("tots: {every_s: 60, parts: 10}\n", "p.yaml:1: tots",
     "unknown key 'tots' (did you mean 'totes'?)"),
    ("totes: {every_s: 0, parts: 10}\n", "p.yaml:1: totes.every_s", "must be > 0, got 0"),
    ("totes:\n  every_s: 60\n  parts: 10\n  drift_s: 100\n", "p.yaml:4: totes.drift_s",
     "drift_s needs drift_to"),
    ("totes: {every_s: 60, parts: 10, mix: {lens: -1}}\n", "p.yaml:1: totes.mix.lens",
     "must be >= 0, got -1"),
    ("friction:\n  - {at_s: 10, lift: 3}\n", "p.yaml:2: friction[0].lift",
     "must be in [0, 2], got 3"),
    ("friction:\n  - {at_s: 100, lift: 0.5}\n  - {at_s: 50, lift: 1}\n",
     "p.yaml:3: friction[1].at_s", "changes must be in time order"),
    ("operator:\n  - {at_s: 10, override_pct: 150}\n", "p.yaml:2: operator[0].override_pct",
     "must be in (0, 100], got 150"),
    ("operator:\n  - {at_s: 10, override_pct: 50, for_s: 60}\n"
     "  - {at_s: 30, override_pct: 70}\n", "p.yaml:3: operator[1].at_s", "overlaps operator[0]"),
    ("start: {lens: 1.5}\n", "p.yaml:1: start.lens", "expected an integer"),
])
def test_a_bad_plan_is_one_line(tmp_path, capsys, text, where, what):
    path = _plan(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_supply_plan(path)
    line = str(e.value)
    assert "\n" not in line and where in line and what in line
    assert main(["check", str(path)]) == 2
    assert capsys.readouterr().err.splitlines()[0].startswith(str(path))


def test_run_refuses_a_bad_plan_a_wrong_part_type_and_other_cells(tmp_path, capsys):
    scn = str(ROOT / "scenarios/lenses.yaml")
    bad = _plan(tmp_path, "totes: {every_s: 60, parts: 10, mix: {lense: 1}}\n")
    assert main(["run", scn, "--fast", "--no-db", "--view", "none", "--supply", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "p.yaml:1: totes.mix.lense: unknown part type 'lense' " \
        "(did you mean 'lens'?)" in err
    good = str(ROOT / "supply/operator_slow.yaml")
    assert main(["run", scn, "--hal", "emulated", "--no-db", "--view", "none",
                 "--supply", good]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "supply plans drive the simulated cell" in err
    assert main(["run", scn, "--fast", "--no-db", "--supply", str(ROOT / "faults/shift.yaml")]) == 2
    assert "is a fault plan, not a supply plan (--supply)" in capsys.readouterr().err
    with pytest.raises(FeederError, match="simulated cell only"):
        apply_supply(object(), load_supply_plan(good))


# ---------------------------------------------------------------------------- effects


def test_tote_counts_add_up_and_follow_the_weights():
    assert tote_counts(10, {"a": 1, "b": 1, "c": 1}) == {"a": 4, "b": 3, "c": 3}
    assert tote_counts(7, {"a": 0.8, "b": 0.2}) == {"a": 6, "b": 1}
    assert sum(tote_counts(199, {"a": 0.3, "b": 0.3, "c": 0.4}).values()) == 199


def test_totes_refill_a_hopper_that_drains_between_them(lenses):
    plan = SupplyPlanSpec(start={"lens": 20}, totes=Totes(every_s=60.0, parts=30))
    hal, clock, driver = _hal(lenses, plan)
    hal.conveyors["horizontal"].set_speed(150.0)
    hal.conveyors["incline"].set_speed(60.0)
    w = hal.world
    sizes = []
    for t in (59.9, 60.1, 119.9, 120.1):
        _to(hal, clock, t)
        sizes.append(len(w.hopper))
    assert sizes[0] < 20 and sizes[1] >= sizes[0] + 29          # drained, then a tote
    assert sizes[2] < sizes[1] and sizes[3] >= sizes[2] + 29
    _to(hal, clock, 200.0)
    assert driver.totes == 3 and w.counts["supplied"] == 90 and w.total == 110
    assert w.audit() == [] and sum(w.census().values()) == w.total
    assert sorted(w.parts) == list(range(1, 111))                # every tote part a new id
    assert [e["t"] for e in driver.log] == [60.0, 120.0, 180.0]
    hal.close()


def test_batch_refill_lowers_parts_per_minute_and_ships_every_part_it_places(plain):
    r = _run_plan_text("start: {lens: 15}\nship_placed: true\n"
                       "totes: {every_s: 25, parts: 10}\n", RUN_S)
    assert r["parts_per_minute"] < 0.5 * plain[0]["parts_per_minute"]
    p, census = r["parts"], r["world"]["census"]
    assert r["supply"]["totes"] == 3 and p["supplied"] == 15 + 3 * 10
    assert p["shipped"] > 0 and census["shipped"] == p["shipped"]
    assert p["supplied"] == sum(census.values())                 # nothing lost, nothing made
    assert p["lost"] == 0 and p["duplicated"] == 0
    assert p["shipped"] + census["placed"] + census["gripper"] == sum(p["retrieved"].values())


def _run_plan_text(text: str, seconds: float) -> dict:
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "plan.yaml"
        path.write_text(text)
        return _run(str(path), seconds)


def test_friction_lowers_the_lift_and_a_zero_lift_stops_the_release(lenses):
    def releases(lift_at_0: float | None) -> int:
        plan = SupplyPlanSpec(friction=[]) if lift_at_0 is None else load_plan_friction(
            lift_at_0)
        hal, clock, _ = _hal(lenses, plan)
        hal.conveyors["horizontal"].set_speed(150.0)
        hal.conveyors["incline"].set_speed(20.0)
        _to(hal, clock, 200.0)
        n = hal.world.counts["released"]
        hal.close()
        return n

    full, half, none = releases(None), releases(0.5), releases(0.0)
    assert 0.35 < half / full < 0.65
    assert none <= 1                        # at most the release drawn before the change


def load_plan_friction(lift: float) -> SupplyPlanSpec:
    from feeder_bt.config.supply import FrictionChange
    return SupplyPlanSpec(friction=[FrictionChange(at_s=0.0, lift=lift)])


def test_a_friction_ramp_steps_the_lift(lenses):
    from feeder_bt.config.supply import FrictionChange
    plan = SupplyPlanSpec(friction=[FrictionChange(at_s=10.0, lift=0.5, ramp_s=20.0)])
    hal, clock, driver = _hal(lenses, plan)
    _to(hal, clock, 21.0)
    assert hal.world.lift == pytest.approx(0.75)
    _to(hal, clock, 40.0)
    assert hal.world.lift == pytest.approx(0.5)
    assert [e["detail"] for e in driver.log] == [
        "incline lift ramps from 100% to 50% of its nominal rate over 20 s"]
    hal.close()


def test_the_operator_slows_the_robot_for_a_while(lenses):
    from feeder_bt.config.supply import OperatorSlow
    from feeder_bt.sim.faults import _event_time
    plan = SupplyPlanSpec(operator=[OperatorSlow(at_s=10.0, override_pct=50.0, for_s=20.0)])
    hal, clock, _ = _hal(lenses, plan)
    w = hal.world

    def move_time(x: float) -> float:
        t0 = clock.now()
        job = hal.robot.move_to(Pose(x, 300.0))
        t_end = _event_time(w, job.seq)
        _to(hal, clock, t_end + 0.01)
        assert job.ok
        return t_end - t0

    move_time(1000.0)                               # from the safe pose
    fast = move_time(1300.0)                        # 300 mm along the belt
    _to(hal, clock, 11.0)
    assert w.speed_override_pct == 50.0 and w.robot_speed_pct == 50.0
    slow = move_time(1000.0)                        # the same 300 mm, back the other way
    assert slow == pytest.approx(2 * fast, rel=0.12)   # each move varies (robot_time_cv)
    _to(hal, clock, 31.0)
    assert w.robot_speed_pct == 100.0 and move_time(1300.0) == pytest.approx(fast, rel=0.12)
    hal.robot.set_speed(80.0)                       # the override multiplies the command
    _to(hal, clock, clock.now() + 0.5)
    assert w.robot_speed_pct == 80.0
    hal.close()


def test_the_operator_plan_lowers_parts_per_minute(plain):
    slow = _run_plan_text("operator:\n  - {at_s: 0, override_pct: 25}\n", RUN_S)
    assert slow["parts_per_minute"] < 0.8 * plain[0]["parts_per_minute"]


def test_the_tote_mix_drifts(mixed):
    plan = SupplyPlanSpec(start={"lens": 0, "square": 0},
                          totes=Totes(every_s=10.0, parts=40, first_at_s=0.0,
                                      mix={"lens": 0.9, "square": 0.1},
                                      drift_to={"lens": 0.1, "square": 0.9}, drift_s=100.0))
    hal, clock, driver = _hal(mixed, plan)
    _to(hal, clock, 101.0)                          # belts still: the totes stay in the hopper
    w = hal.world
    types = [w.parts[pid].type for pid in sorted(w.parts)]
    first, last = types[:40], types[-40:]
    assert first.count("lens") == 36 and last.count("square") == 36
    middle = types[200:240]                          # the tote at 50 s: half and half
    assert middle.count("lens") == 20
    assert driver.mix(w.t) == pytest.approx({"lens": 0.1, "square": 0.9})
    assert w.audit() == [] and sum(w.census().values()) == w.total == 440
    hal.close()


# ---------------------------------------------------------------------------- accounting


def _grip_and_place(hal, clock, scenario):
    w = hal.world
    for r in sorted(w.truth(), key=lambda r: -r["x_mm"]):
        if r["pickable"] and r["singulated"]:
            target = PickTarget(r["id"], r["x_mm"], r["y_mm"], r["angle_deg"], w.robot_track_count(w.now()))
            job = hal.robot.pick(target)
            if job.done:
                continue
            _to(hal, clock, clock.now() + 3.0)
            if job.ok:
                place = scenario.parts[r["type"]].place
                hal.robot.place(Pose(place.x, place.y))
                _to(hal, clock, clock.now() + 3.0)
                return r["id"]
    raise AssertionError("nothing to grip")


def test_a_shipped_part_leaves_by_identity_and_a_broken_shipment_is_counted(lenses):
    plan = SupplyPlanSpec(ship_placed=True, totes=Totes(every_s=20.0, parts=5))
    hal, clock, _ = _hal(lenses, plan)
    hal.conveyors["horizontal"].set_speed(150.0)
    hal.conveyors["incline"].set_speed(60.0)
    _to(hal, clock, 40.0)
    w = hal.world
    pid = _grip_and_place(hal, clock, lenses[0])
    _to(hal, clock, clock.now() + RECYCLE_S + 1.0)
    assert w.parts[pid].where == "shipped" and w.shipped == [pid]
    assert w.audit() == [] and w.problems == []
    assert sum(w.census().values()) == w.total == 300 + w.counts["supplied"]
    w.hopper.append(pid)                      # the bug: a shipped part back in the hopper
    _to(hal, clock, clock.now() + 0.5)
    tote_part = max(w.parts)
    assert w.parts[tote_part].where == "hopper"
    w.hopper.remove(tote_part)                # ... and a tote part that vanished
    _to(hal, clock, clock.now() + 0.5)
    found = sorted((p["kind"], p["id"]) for p in w.problems)
    assert found == [("duplicated", pid), ("lost", tote_part)]
    assert w.lost() == 1 and w.duplicated() == 1 and w.broken
    hal.close()


# ---------------------------------------------------------------------------- supply bound


def test_reach_window_spans(lenses):
    reach = ReachWindow(lenses[1], lenses[0])     # base (1370, 305), reach 600, inner 160
    (lo, hi), = reach.spans(305.0 + 300.0)        # outside the inner circle: one span
    assert lo == pytest.approx(1370 - (600 ** 2 - 300 ** 2) ** 0.5) and hi == 1190.0
    assert reach.spans(305.0 + 601.0) == []
    assert reach.crosses(100.0, 305.0) and not reach.crosses(1195.0, 305.0)
    assert not reach.crosses(100.0, 305.0 + 650.0)


def test_the_supply_bound_matches_the_worlds_truth(plain):
    """The controller's count (located pickable parts whose path meets the reach, per
    minute) against the world's truth (the ``plain`` fixture)."""
    r, truth = plain
    truth_ppm = truth * 60.0 / r["feed_seconds"]
    landed_ppm = r["world"]["landed"] * 60.0 / r["feed_seconds"]
    assert r["supply_bound_ppm"] == pytest.approx(truth_ppm, rel=0.05)
    assert r["supply_bound_ppm"] <= landed_ppm
    known = {"supply": r["supply_bound_ppm"], "robot": r["robot_bound_ppm"]}
    assert r["ceiling_ppm"] == min(known.values())
    assert known[r["ceiling"]] == r["ceiling_ppm"]
    assert r["of_ceiling_pct"] == pytest.approx(
        100 * r["parts_per_minute"] / r["ceiling_ppm"], abs=0.1)
    assert r["parts_per_minute"] <= r["ceiling_ppm"]


def test_the_summary_names_the_ceiling_in_80_columns(plain):
    from feeder_bt.analysis.summary import summary
    r = plain[0]
    lines = summary(r).splitlines()
    i = next(i for i, s in enumerate(lines) if s.startswith("  ceiling "))
    assert lines[i] == (f"  ceiling {r['ceiling_ppm']:.1f} parts/min ({r['ceiling']} bound): "
                        f"{r['of_ceiling_pct']:.0f} % of it")
    assert lines[i + 1] == (f"  bounds: robot {r['robot_bound_ppm']:.1f} corner, "
                            f"supply {r['supply_bound_ppm']:.1f}")
    assert lines[i + 2] == (f"  yardsticks, not bounds: {r['robot_bound_mean_ppm']:.1f} mean "
                            f"cycle, {r['robot_bound_selection_ppm']:.1f} nearest-first "
                            f"(run {r['of_selection']:.2f}x)")
    assert all(len(line) <= 80 for line in lines[i: i + 3])
