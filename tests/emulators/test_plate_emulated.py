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
                        lambda kind, scenario, cell, seed: start_emulated(scenario, cell, seed,
                                                                          faults=plan))
    r = run_job(RunOptions(scenario="scenarios/plate_lenses.yaml", hal="emulated",
                           duration=60.0, seed=1, view="none", db=None))
    assert [kind for _, kind, _ in plan.log] == ["servo_timeout"]
    assert r["state"] == "STOPPED" and r["fault"] is None
    assert r["faults"].get("plate") == 1 and r["recoveries"].get("plate") == 1
    assert r["parts"]["lost"] == 0 and r["parts"]["duplicated"] == 0
    assert r["parts"]["retrieved"]["lens"] >= 5
