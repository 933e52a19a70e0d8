"""Fault injection in the simulated cell, driven by hand on virtual time.

Each kind of fault: the job fails with the right typed error at the right virtual time, the
device stays faulty exactly as long as it should, nothing is counted that did not happen,
runs repeat with the same seeds, and every part stays accounted for.
"""

from __future__ import annotations

import dataclasses

import pytest

from feeder_bt.config import load_scenario
from feeder_bt.config.faults import FaultPlanSpec, FaultRate, ScriptedFault
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import (
    CommsLost,
    ConfigError,
    ConveyorFault,
    FeederError,
    GrabFailed,
    MissedGrab,
    ServoTimeout,
)
from feeder_bt.core.jobs import JobState
from feeder_bt.core.model import SimImperfections
from feeder_bt.hal.interfaces import Held, PickTarget, Pose
from feeder_bt.hal.mock.hal import MockHal
from feeder_bt.sim.devices import make_sim_hal
from feeder_bt.sim.faults import POWER_OFF, FaultInjector, inject_faults

EPS = 1e-6
WARM_S = 30.0          # belts running this long put pickable parts in the robot's reach


@pytest.fixture(scope="module")
def lenses():
    """The ideal cell: the rig plays the locator by the truth and predicts grip times with
    the nominal robot model (the imperfections have their own tests)."""
    scenario, cell = load_scenario("scenarios/lenses.yaml")
    return scenario, dataclasses.replace(cell, sim=SimImperfections(ideal=True))


class Rig:
    """A bare simulated cell and its clock, stepped by the test."""

    def __init__(self, lenses, plan: FaultPlanSpec | None = None, seed: int = 5,
                 run_seed: int | None = None) -> None:
        scenario, cell = lenses
        self.clock = SimClock()
        self.hal = make_sim_hal(scenario, cell, self.clock, seed)
        self.world = self.hal.world
        self.inj: FaultInjector | None = (inject_faults(self.hal, plan, run_seed)
                                          if plan is not None else None)

    def to(self, t: float, dt: float = 0.25) -> None:
        now = self.clock.now()
        while now < t - 1e-12:
            now = min(t, now + dt)
            self.clock.advance_to(now)
            self.hal.step(now)

    def belts(self, h: float = 150.0, i: float = 60.0) -> None:
        self.hal.conveyors["horizontal"].set_speed(h)
        self.hal.conveyors["incline"].set_speed(i)

    def target(self) -> PickTarget:
        """A part the robot can pick now (by the truth: the test plays the locator)."""
        w = self.world
        for r in sorted(w.truth(), key=lambda r: -r["x_mm"]):
            if not (r["pickable"] and r["singulated"]):
                continue
            t = PickTarget(r["id"], r["x_mm"], r["y_mm"], r["angle_deg"], w.robot_track_count(w.now()))
            try:
                _, t_grip = w.plan_pick(t, w.now())
            except FeederError:
                continue
            # as the controller's too_far rule: not a part the belt carries off its end
            # before the grip (the world's SCARA takes longer to the far side)
            if w.commanded_xy(t, t_grip)[0] > w.scenario.retrieve.too_far_mm:
                continue
            return t
        raise AssertionError("no pickable part in reach")

    def grip_time(self, target: PickTarget) -> float:
        w = self.world
        return w.plan_pick(target, w.now() + w.cell.robot.command_overhead_s)[1]

    def close(self) -> None:
        self.world.check_accounting()
        assert self.world.lost() == 0
        self.hal.close()


@pytest.fixture
def rig(lenses):
    rigs: list[Rig] = []

    def make(plan: FaultPlanSpec | None = None, **kw) -> Rig:
        r = Rig(lenses, plan, **kw)
        rigs.append(r)
        return r

    yield make
    for r in rigs:
        r.close()


def plan(rates=None, scripted=(), seed=0) -> FaultPlanSpec:
    return FaultPlanSpec(seed=seed, rates=dict(rates or {}), scripted=list(scripted))


def warm(r: Rig) -> None:
    r.belts()
    r.to(WARM_S)


# ---------------------------------------------------------------------------- robot


def test_servo_timeout_fails_the_pick_half_way_and_powers_the_arm_off(rig):
    r = rig(plan({"servo_timeout": FaultRate(per_pick=1.0)}))
    warm(r)
    target = r.target()
    t0, t_grip = r.clock.now(), r.grip_time(target)
    job = r.hal.robot.pick(target)
    t_fail = t0 + 0.5 * (t_grip - t0)
    r.to(t_fail - EPS, dt=0.01)
    assert job.state is JobState.RUNNING and r.inj.injected["servo_timeout"] == 0
    r.to(t_fail)
    assert job.state is JobState.FAILED and isinstance(job.error, ServoTimeout)
    assert job.error.kind == "servo_timeout"
    assert target.part_id in r.world.on_horizontal        # the part stays on the belt
    assert r.world.gripper is None and r.world.robot_busy is None
    assert r.inj.injected == {"servo_timeout": 1} and not r.inj.power_on
    assert r.inj.log[0]["t"] == pytest.approx(t_fail) and r.inj.log[0]["device"] == "adept"

    # power off: every motion fails at once, until the recovery program has run
    robot = r.hal.robot
    for refused in (robot.pick(r.target()), robot.place(Pose(1330, -120)),
                    robot.move_to(Pose(1300, 0)), robot.move_safe()):
        assert refused.state is JobState.FAILED and isinstance(refused.error, ServoTimeout)
        assert str(refused.error) == POWER_OFF
    assert robot.set_speed(50).ok                          # not a motion
    t_rec = r.clock.now()
    rec = robot.recover()
    r.to(t_rec + 2.0 - EPS, dt=0.01)
    assert not rec.done and not r.inj.power_on
    r.to(t_rec + 2.0)
    assert rec.ok and r.inj.power_on
    move = robot.move_safe()
    r.to(r.clock.now() + 2.0)
    assert move.ok
    assert r.inj.injected == {"servo_timeout": 1}          # the refusals were not new faults


def test_a_pick_cancelled_before_the_servo_fault_injects_nothing(rig):
    r = rig(plan({"servo_timeout": FaultRate(per_pick=1.0)}))
    warm(r)
    target = r.target()
    job = r.hal.robot.pick(target)
    r.to(r.clock.now() + 0.01, dt=0.01)
    job.cancel()
    assert target.part_id in r.world.on_horizontal
    r.to(r.clock.now() + 2.0)
    assert job.state is JobState.CANCELLED and r.inj.power_on
    assert r.inj.injected == {} and r.inj.log == [] and r.world.gripper is None


def test_missed_grab_fails_at_the_grip_time(rig):
    r = rig(plan({"missed_grab": FaultRate(per_pick=1.0)}))
    warm(r)
    target = r.target()
    t_grip = r.grip_time(target)
    job = r.hal.robot.pick(target)
    r.to(t_grip - EPS, dt=0.01)
    assert not job.done
    r.to(t_grip)
    assert job.state is JobState.FAILED and isinstance(job.error, MissedGrab)
    assert target.part_id in r.world.on_horizontal and r.world.gripper is None
    assert r.inj.injected == {"missed_grab": 1} and r.inj.power_on
    assert r.world.robot_busy is None
    after = r.hal.robot.move_safe()                        # the robot is free at once
    r.to(r.clock.now() + 2.0)
    assert after.ok


def test_without_faults_the_same_pick_succeeds(rig):
    r = rig(plan())
    warm(r)
    target = r.target()
    t_grip = r.grip_time(target)
    job = r.hal.robot.pick(target)
    r.to(t_grip)
    assert job.ok and r.world.gripper == target.part_id
    assert r.inj.injected == {}


def test_scripted_pick_faults_arm_the_next_pick(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=WARM_S - 1, kind="missed_grab")]))
    warm(r)
    assert r.inj.injected == {}                            # armed, not yet injected
    target = r.target()
    job = r.hal.robot.pick(target)
    r.to(r.grip_time(target) + 0.01, dt=0.01)
    assert isinstance(job.error, MissedGrab) and r.inj.injected == {"missed_grab": 1}
    second = r.hal.robot.pick(r.target())
    r.to(r.clock.now() + 2.0, dt=0.01)
    assert second.done and not isinstance(second.error, MissedGrab)


# ---------------------------------------------------------------------------- links


def test_adept_link_drop_loses_the_picks_reply_but_the_robot_finishes_the_pick(rig):
    drop_at = WARM_S + 0.1
    r = rig(plan(scripted=[ScriptedFault(at_s=drop_at, kind="comms_lost", device="adept",
                                         outage_s=2.0)]))
    warm(r)
    target = r.target()
    t_grip = r.grip_time(target)
    assert t_grip > drop_at
    job = r.hal.robot.pick(target)
    r.to(drop_at - EPS, dt=0.01)
    assert not job.done
    enc_before = r.hal.robot_position.belt_encoder()
    r.to(drop_at)
    # the cell hears nothing more, but the controller goes on with the pick
    assert job.state is JobState.FAILED and isinstance(job.error, CommsLost)
    assert target.part_id in r.world.on_horizontal and r.world.robot_busy is not None
    assert r.inj.injected == {"comms_lost": 1} and r.inj.log[0]["device"] == "adept"
    r.to(t_grip)
    assert r.world.gripper == target.part_id and r.world.robot_busy.done
    # reads keep their last value while the belt moves on
    r.to(drop_at + 1.0, dt=0.1)
    frozen = r.hal.robot_position.belt_encoder()
    assert frozen == pytest.approx(enc_before, abs=20 * 150 * 0.02)   # within one step
    assert r.world.robot_count() != frozen
    for call in (lambda: r.hal.robot.move_safe(), lambda: r.hal.robot.recover(),
                 lambda: r.hal.robot.set_speed(80), lambda: r.hal.robot.held()):
        j = call()
        assert j.state is JobState.FAILED and isinstance(j.error, CommsLost)
    r.to(drop_at + 2.0 - EPS, dt=0.01)
    assert isinstance(r.hal.robot.move_safe().error, CommsLost)
    r.to(drop_at + 2.0)
    assert r.hal.robot_position.belt_encoder() == r.world.robot_count()
    # back: the controller says what it gripped, by the id the pick carried
    held = r.hal.robot.held()
    assert held.ok and held.result == Held(target.part_id, False, None)
    move = r.hal.robot.move_safe()
    r.to(r.clock.now() + 2.0)
    assert move.ok and r.inj.injected == {"comms_lost": 1}


def test_adept_link_drop_during_a_place_loses_the_reply_and_the_part_is_placed(rig, lenses):
    r = rig()
    warm(r)
    target = r.target()
    pick = r.hal.robot.pick(target)
    r.to(r.grip_time(target), dt=0.01)
    assert pick.ok and r.world.gripper == target.part_id
    # a plan injected now counts its times from now: the link drops 50 ms into the place
    t_place = r.clock.now()
    r.inj = inject_faults(r.hal, plan(scripted=[ScriptedFault(
        at_s=0.05, kind="comms_lost", device="adept", outage_s=3.0)]))
    spec = lenses[0].parts["lens"].place
    place = r.hal.robot.place(Pose(spec.x, spec.y))
    r.to(t_place + 0.05, dt=0.01)
    assert place.state is JobState.FAILED and isinstance(place.error, CommsLost)
    assert r.world.gripper == target.part_id             # still on its way
    asked = r.hal.robot.held()
    assert isinstance(asked.error, CommsLost)              # nobody to ask yet
    r.to(t_place + 0.05 + 3.0)
    assert r.world.gripper is None
    assert r.world.parts[target.part_id].where == "placed"
    held = r.hal.robot.held()
    assert held.ok and held.result == Held(None, False, target.part_id)
    assert r.world.misplaced_by_type == {}


def test_galil_link_drop_fails_notifications_but_the_belts_run_on(rig):
    """An outage shorter than the card's host watchdog (galil.watchdog_s, 1 s): the belts
    run on as commanded."""
    r = rig(plan(scripted=[ScriptedFault(at_s=WARM_S + 0.2, kind="comms_lost",
                                         device="galil", outage_s=0.9)]))
    warm(r)
    h = r.hal.conveyors["horizontal"]
    note = h.travelled(100.0)                        # due at +0.667 s at 150 mm/s
    pos0 = r.world.horizontal.pos(r.clock.now())
    r.to(WARM_S + 0.2)
    assert note.state is JobState.FAILED and isinstance(note.error, CommsLost)
    assert not r.world.notifications
    frozen = h.position()
    for j in (h.set_speed(10), h.stop(), h.move(5, 5), h.shake(5, 1), h.travelled(5)):
        assert j.state is JobState.FAILED and isinstance(j.error, CommsLost)
    r.to(WARM_S + 1.0, dt=0.1)
    assert h.position() == frozen and h.speed() == 150.0
    assert r.world.horizontal.pos(WARM_S + 1.0) - pos0 == pytest.approx(150.0 * 1.0)
    r.to(WARM_S + 1.2)
    assert h.position() == r.world.galil_count() and h.fault() is None
    assert r.world.horizontal.vel(WARM_S + 1.2) == pytest.approx(150.0)
    note = h.travelled(15.0)
    r.to(WARM_S + 1.4)
    assert note.ok and r.inj.injected == {"comms_lost": 1} and r.inj.watchdog_stops == 0


def test_a_longer_galil_outage_is_ended_by_the_cards_watchdog(rig):
    """Silent for galil.watchdog_s, the card stops every belt (#WDOG in monitor.dmc); once
    the link is back each conveyor's fault() says so in the real driver's words, until
    the next command starts the belt again."""
    from feeder_bt.hal.interfaces import watchdog_stopped
    r = rig(plan(scripted=[ScriptedFault(at_s=WARM_S + 0.2, kind="comms_lost",
                                         device="galil", outage_s=2.0)]))
    warm(r)
    h, inc = r.hal.conveyors["horizontal"], r.hal.conveyors["incline"]
    r.to(WARM_S + 1.2 - EPS, dt=0.1)
    assert r.world.horizontal.vel(r.clock.now()) == pytest.approx(150.0)
    r.to(WARM_S + 1.5, dt=0.1)                       # stopped at 1500 mm/s² in 0.1 s
    assert r.world.horizontal.vel(WARM_S + 1.5) == 0.0
    assert r.world.incline.vel(WARM_S + 1.5) == 0.0
    assert h.fault() is None and h.speed() == 150.0  # the link is down: nothing heard yet
    r.to(WARM_S + 2.3)
    assert h.speed() == 0.0
    for conv in (h, inc):
        err = conv.fault()
        assert isinstance(err, ConveyorFault)
        assert str(err) == str(watchdog_stopped(conv.name, 1.0))
    assert r.inj.watchdog_stops == 1 and "watchdog stopped the belts" in r.inj.log[0]["detail"]
    job = h.set_speed(150.0)
    assert h.fault() is None and inc.fault() is not None
    r.to(WARM_S + 3.0)
    assert job.ok and r.world.horizontal.vel(WARM_S + 3.0) == pytest.approx(150.0)


def test_without_the_watchdog_the_belts_run_through_a_long_outage(lenses):
    """galil.watchdog_s: 0 (no #WDOG on the card): nothing stops the belts."""
    scenario, cell = lenses
    r = Rig((scenario, dataclasses.replace(cell, galil=dataclasses.replace(
        cell.galil, watchdog_s=0.0))), plan(scripted=[ScriptedFault(
            at_s=WARM_S + 0.2, kind="comms_lost", device="galil", outage_s=3.0)]))
    warm(r)
    r.to(WARM_S + 3.5, dt=0.25)
    assert r.world.horizontal.vel(WARM_S + 3.5) == pytest.approx(150.0)
    assert r.hal.conveyors["horizontal"].fault() is None and r.inj.watchdog_stops == 0
    r.close()


def test_galil_link_drop_fails_a_move_in_flight(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=1.0, kind="comms_lost", device="galil")]))
    move = r.hal.conveyors["incline"].move(1000.0, 200.0)
    r.to(1.0)
    assert isinstance(move.error, CommsLost)
    assert r.world.incline.vel(1.5) == pytest.approx(200.0)   # still moving as commanded


def test_camera_link_drop_and_grab_failures(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=5.0, kind="comms_lost", device="camera",
                                         outage_s=1.0)]))
    grab_s = r.world.cell.camera.grab_s
    r.to(5.0)
    g = r.hal.camera.grab()
    assert g.state is JobState.FAILED and isinstance(g.error, CommsLost)
    r.to(6.0)
    g = r.hal.camera.grab()
    r.to(6.0 + grab_s)
    assert g.ok and g.result.image.size > 0


def test_grab_failed_fails_after_the_grab_time_with_no_image(rig):
    r = rig(plan({"grab_failed": FaultRate(per_frame=1.0)}))
    grab_s = r.world.cell.camera.grab_s
    r.to(2.0)
    frames = r.hal.camera.frames
    g = r.hal.camera.grab()
    r.to(2.0 + grab_s - EPS, dt=0.001)
    assert not g.done and r.inj.injected == {}
    r.to(2.0 + grab_s)
    assert g.state is JobState.FAILED and isinstance(g.error, GrabFailed)
    assert g.result is None and g.error.kind == "grab_failed"
    assert r.inj.injected == {"grab_failed": 1} and r.hal.camera.frames == frames + 1


def test_grab_failure_rate_per_frame(rig):
    r = rig(plan({"grab_failed": FaultRate(per_frame=0.2)}, seed=3))
    grab_s = r.world.cell.camera.grab_s
    failed = 0
    for _ in range(100):
        g = r.hal.camera.grab()
        r.to(r.clock.now() + grab_s)
        assert g.done
        failed += isinstance(g.error, GrabFailed)
    assert failed == r.inj.injected["grab_failed"]
    assert 8 <= failed <= 35


# ---------------------------------------------------------------------------- belt, e-stop


def test_conveyor_jam_stops_the_belt_until_a_motion_command(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=10.0, kind="conveyor_jam")]))
    r.belts()
    h, inc = r.hal.conveyors["horizontal"], r.hal.conveyors["incline"]
    r.to(10.0 - EPS, dt=0.5)
    assert h.fault() is None
    r.to(10.0)
    err = h.fault()
    assert isinstance(err, ConveyorFault) and err.kind == "conveyor"
    assert str(err) == "horizontal conveyor stalled"
    assert inc.fault() is None and r.inj.injected == {"conveyor_jam": 1}
    r.to(12.0)
    assert r.world.horizontal.vel(12.0) == 0.0 and h.speed() == 0.0
    assert r.world.incline.vel(12.0) == pytest.approx(60.0)
    assert h.fault() is err                           # stays until a command
    assert r.inj.unseen == {}
    job = h.set_speed(150.0)
    assert h.fault() is None
    r.to(13.0)
    assert job.ok and r.world.horizontal.vel(13.0) == pytest.approx(150.0)


def test_a_jam_fails_the_move_in_flight(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=1.0, kind="conveyor_jam")]))
    move = r.hal.conveyors["horizontal"].move(1000.0, 300.0)
    r.to(1.0)
    assert isinstance(move.error, ConveyorFault)
    r.to(3.0)
    assert r.world.horizontal.vel(3.0) == 0.0
    shake = r.hal.conveyors["horizontal"].shake(10.0, 2)
    assert r.hal.conveyors["horizontal"].fault() is None
    r.to(5.0)
    assert shake.ok


def test_a_stopped_belt_does_not_jam(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=1.0, kind="conveyor_jam")]))
    r.to(2.0)
    assert r.hal.conveyors["horizontal"].fault() is None and r.inj.injected == {}


def test_estop_input_is_pressed_and_released(rig):
    r = rig(plan(scripted=[ScriptedFault(at_s=5.0, kind="estop", release_after_s=60.0)]))
    io = r.hal.io
    r.to(5.0 - EPS, dt=1.0)
    assert io.get("estop") is False
    r.to(5.0)
    assert io.get("estop") is True and r.world.io["estop"] is True
    assert r.inj.injected == {"estop": 1}
    r.to(65.0 - EPS, dt=1.0)
    assert io.get("estop") is True
    r.to(65.0)
    assert io.get("estop") is False
    changes = io.changes()
    assert [(c.signal, c.value, c.t) for c in changes] == [("estop", True, 5.0),
                                                           ("estop", False, 65.0)]
    assert io.changes() == []


def test_estop_needs_an_estop_input(lenses):
    scenario, cell = lenses
    cell = dataclasses.replace(cell, io={k: v for k, v in cell.io.items() if k != "estop"})
    hal = make_sim_hal(scenario, cell, SimClock(), 1)
    try:
        robot = hal.robot
        with pytest.raises(ConfigError, match="no 'estop' input"):
            inject_faults(hal, plan(scripted=[ScriptedFault(at_s=1.0, kind="estop")]))
        assert hal.robot is robot                 # nothing was wrapped
    finally:
        hal.close()


def test_a_plate_link_cut_needs_a_plate(lenses):
    scenario, cell = lenses
    hal = make_sim_hal(scenario, cell, SimClock(), 1)
    try:
        with pytest.raises(ConfigError, match="no plate feeder"):
            inject_faults(hal, plan(scripted=[ScriptedFault(at_s=1.0, kind="comms_lost",
                                                            device="plate")]))
    finally:
        hal.close()


def test_a_plate_link_cut_loses_the_reply_not_the_action():
    """The plate's line drops during a flip: the cell's job fails with the lost link,
    the plate finishes the flip, and an action sent while the line is down is refused."""
    from feeder_bt.sim.plate import make_plate_sim_hal
    scenario, cell = load_scenario("scenarios/plate_lenses.yaml")
    clock = SimClock()
    hal = make_plate_sim_hal(scenario, cell, clock, 1)
    try:
        inj = inject_faults(hal, plan(scripted=[ScriptedFault(
            at_s=3.0, kind="comms_lost", device="plate", outage_s=2.0, link="refused")]))
        init = hal.plate.init()
        while not init.done:
            clock.advance(0.05)
            hal.world.now()
        assert init.ok, init.error
        clock.advance(3.0 - clock.now() - 0.01)
        flip = hal.plate.flip(4)
        clock.advance(0.02)
        hal.world.now()
        assert flip.done and isinstance(flip.error, CommsLost)
        assert isinstance(hal.plate.dispense(1).error, CommsLost)
        flipping = hal.plate._inner.busy           # the plate's own flip goes on
        clock.advance(3.0)
        hal.world.now()
        assert flipping is not None and flipping.ok
        assert inj.injected["comms_lost"] == 1
        again = hal.plate.feed(1, 1)            # the line is back: the action is sent
        assert again.error is None
    finally:
        hal.close()


def test_only_the_simulated_cell_takes_a_plan_and_only_one(rig):
    with pytest.raises(FeederError, match="simulated cell only"):
        inject_faults(MockHal(), plan())
    r = rig(plan())
    with pytest.raises(FeederError, match="already has a fault plan"):
        inject_faults(r.hal, plan())


# ---------------------------------------------------------------------------- rates, seeds


def comms_run(lenses, plan_seed=0, run_seed=None, hours=1.0, per_hour=60.0):
    r = Rig(lenses, plan({"comms_lost": FaultRate(per_hour=per_hour, outage_s=2.0)},
                         seed=plan_seed), run_seed=run_seed)
    try:
        r.to(3600.0 * hours, dt=30.0)
        return r.inj.log, r.inj.injected, r.world.rng.random()
    finally:
        r.close()


def test_per_hour_arrivals_alternate_links_and_repeat_with_the_same_seeds(lenses):
    log, injected, world_draw = comms_run(lenses)
    assert 40 <= injected["comms_lost"] <= 85
    devices = [e["device"] for e in log]
    assert devices == ["galil", "adept"] * (len(devices) // 2) + ["galil"] * (len(devices) % 2)
    times = [e["t"] for e in log]
    assert times == sorted(times) and times[0] > 0
    assert comms_run(lenses) == (log, injected, world_draw)            # repeatable
    other_plan = comms_run(lenses, plan_seed=1)
    other_run = comms_run(lenses, run_seed=99)
    assert other_plan[0] != log and other_run[0] != log
    # the fault draws never touch the world's own random stream
    assert other_plan[2] == other_run[2] == world_draw


def test_faults_leave_the_part_flow_of_the_world_unchanged(rig):
    """Link drops (shorter than the card's watchdog) and failed grabs change nothing in the
    world: same parts, same places."""
    faulty = rig(plan({"comms_lost": FaultRate(per_hour=600.0, device="galil", outage_s=0.8),
                       "grab_failed": FaultRate(per_frame=0.5)}))
    clean = rig()
    for r in (faulty, clean):
        r.belts()
        for k in range(40):
            r.hal.camera.grab()
            r.to(3.0 * (k + 1), dt=0.5)
    assert faulty.inj.injected["comms_lost"] > 5 and faulty.inj.injected["grab_failed"] > 5
    assert faulty.world.census() == clean.world.census()
    assert faulty.world.counts == clean.world.counts
    assert faulty.world.truth() == clean.world.truth()


def test_changeover_keeps_the_plan(rig, lenses):
    r = rig(plan(scripted=[ScriptedFault(at_s=20.0, kind="estop", release_after_s=5.0)]))
    r.to(5.0)
    r.hal.changeover(lenses[0])
    r.world = r.hal.world
    assert r.hal.extras["fault_injector"] is r.inj and r.inj.world is r.world
    r.to(20.0)
    assert r.hal.io.get("estop") and r.inj.injected == {"estop": 1}
    r.to(25.0)
    assert not r.hal.io.get("estop")
