"""The plate cell through the real drivers (AnyFeeder over its serial protocol, V+, Galil
for the backlight and the latch) against the emulators on loopback: it feeds like the
simulated plate cell. Real time (two minutes of wall clock): a soak run,
``python -m pytest -m soak tests/test_plate_emulated.py``."""

from __future__ import annotations

import pytest

from feeder_bt.run import RunOptions, run_job


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
