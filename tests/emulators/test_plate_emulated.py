"""The plate cell through the real drivers (AnyFeeder over its serial protocol, V+, Galil
for the backlight and the latch) against the emulators on loopback: it feeds like the
simulated plate cell. Real time (two minutes of wall clock): a soak run,
``python -m pytest -m soak tests/emulators/test_plate_emulated.py``."""

from __future__ import annotations

import pytest

from feeder_bt.app.run import RunOptions, run_job


@pytest.mark.soak
def test_the_emulated_plate_cell_feeds_like_the_simulated_one():
    opts = dict(scenario="scenarios/plate_lenses.yaml", duration=120.0, seed=1, view="none",
                db=None)
    emulated = run_job(RunOptions(hal="emulated", **opts))
    simulated = run_job(RunOptions(hal="sim", fast=True, **opts))
    assert emulated["hal"] == "emulated" and emulated["state"] == "STOPPED"
    assert emulated["fault"] is None and emulated["parts"]["lost"] == 0
    got, want = emulated["parts_per_minute"], simulated["parts_per_minute"]
    assert want > 20
    assert abs(got - want) <= 0.25 * want, (got, want)


@pytest.mark.soak          # real time: a minute of wall clock through the TCP drivers
def test_a_servo_error_in_an_emulated_run_is_reset_and_feeding_goes_on(monkeypatch):
    """The AnyFeeder emulator ends the plate's third action with ``m13`` (a fault plan's
    ``servo_timeout`` for controller ``plate``): the real driver reports it in the manual's
    words, the present tree resets and homes the plate, and feeding goes on."""
    from feeder_bt.app import run as run_mod
    from feeder_bt.app.factory import start_emulated
    from feeder_bt.emulators.faults import FaultPlan

    plan = FaultPlan()
    plan.add("servo_timeout", "plate", "", nth=3)
    monkeypatch.setattr(run_mod, "make_hal",
                        lambda kind, scenario, cell, seed, world=None: start_emulated(scenario, cell, seed,
                                                                          faults=plan))
    r = run_job(RunOptions(scenario="scenarios/plate_lenses.yaml", hal="emulated",
                           duration=60.0, seed=1, view="none", db=None))
    assert [kind for _, kind, _ in plan.log] == ["servo_timeout"]
    assert r["state"] == "STOPPED" and r["fault"] is None
    assert r["faults"].get("plate") == 1 and r["recoveries"].get("plate") == 1
    assert r["parts"]["lost"] == 0 and r["parts"]["duplicated"] == 0
    assert r["parts"]["retrieved"]["lens"] >= 5


@pytest.mark.soak          # real time: 40 s of wall clock through the TCP drivers
def test_a_plate_that_echoes_reports_its_motors_apart_and_a_late_no_sync_feeds(monkeypatch):
    """The AnyFeeder as real feeders speak: each command echoed, motor 2 reporting 0.4 s
    after motor 1, and in the fourth action motor 2 never starting (``m28`` after motor
    1's ``m10``). The driver reports the ``m28``, the present tree resets and homes the
    plate, nothing is written while a motor is busy, and the cell feeds with lost 0."""
    from feeder_bt.app import run as run_mod
    from feeder_bt.app.factory import start_emulated

    emulators = []

    def make_hal(kind, scenario, cell, seed, world=None):
        hal, clock = start_emulated(scenario, cell, seed, plate_options={
            "echo": True, "motor_gap_s": 0.4, "late_error_at": 4})
        emulators.append(hal.extras["plate_emulator"])
        return hal, clock
    monkeypatch.setattr(run_mod, "make_hal", make_hal)
    r = run_job(RunOptions(scenario="scenarios/plate_lenses.yaml", hal="emulated",
                           duration=40.0, seed=1, view="none", db=None))
    emu = emulators[0]
    assert emu.overlaps == 0 and len(emu.done) >= 5
    assert r["state"] == "STOPPED" and r["fault"] is None
    assert r["faults"].get("plate") == 1 and r["recoveries"].get("plate") == 1
    assert r["parts"]["lost"] == 0 and r["parts"]["duplicated"] == 0
    assert r["parts"]["retrieved"]["lens"] >= 3
