"""The emulated cell (``--hal emulated``) with its camera through pypylon and Basler's camera
emulator: each frame is the plant's belt at the pulse the Galil emulator latched, and the
whole run feeds like the simulated cell (a soak run: real time)."""

from __future__ import annotations

import numpy as np
import pytest

from feeder_bt.scenario.loader import load_scenario
from tests.galil_fixtures import wait_job, wait_until

pytest.importorskip("pypylon", reason="pypylon is not installed (pip install -e '.[pylon]')")

CELL = "cells/sim_pylon.yaml"


@pytest.fixture(autouse=True)
def camemu(monkeypatch):
    monkeypatch.setenv("PYLON_CAMEMU", "1")


def test_emulated_cell_frames_come_through_pylon_paired_with_the_galil_latch():
    from feeder_bt.hal.factory import start_emulated
    sc, cell = load_scenario("scenarios/lenses.yaml", cell=CELL)
    assert cell.camera.source == "pylon:" and cell.camera.pylon.trigger == "Line1"
    hal, _clock = start_emulated(sc, cell, seed=3)
    try:
        bridge = hal.camera.source
        assert type(bridge).__name__ == "PylonPlantCamera"
        rendered = []
        write = bridge.files.write

        def keep(img):
            rendered.append(img.copy())
            write(img)
        bridge.files.write = keep
        belt = hal.conveyors["horizontal"]
        hal.motors_on()
        assert wait_job(belt.set_speed(100.0), 30).ok
        latches = []
        for _ in range(4):
            was = belt.position()           # the belt runs on between two frames
            assert wait_until(lambda was=was: belt.position() > was + 40, 30)
            job = wait_job(hal.camera.grab(), 30)
            assert job.ok, job.error
            frame = job.result
            assert frame.image.shape == (cell.camera.height_px, cell.camera.width_px)
            # the very image the plant rendered at this trigger, not pylon's test image
            assert np.array_equal(frame.image, rendered[-1])
            latches.append(frame.latch)
        assert all(b > a for a, b in zip(latches, latches[1:], strict=False)), latches
        assert bridge.counts() == {"frames": 4, "lost_frames": 0, "extra_triggers": 0}
        assert bridge.index == 4                   # one plant trigger per frame
    finally:
        hal.close()


def test_a_pylon_cell_without_a_camera_is_a_one_line_error(monkeypatch):
    from feeder_bt.errors import ConfigError
    from feeder_bt.hal.factory import start_emulated
    monkeypatch.setenv("PYLON_CAMEMU", "0")
    sc, cell = load_scenario("scenarios/lenses.yaml", cell=CELL)
    with pytest.raises(ConfigError, match=r"camera.source: pylon:: no such pylon camera "
                                          r"\(cameras found: none; PYLON_CAMEMU=N adds"):
        start_emulated(sc, cell, seed=3)


@pytest.mark.soak          # real time: two minutes of wall clock through the TCP drivers
def test_pylon_emulated_run_feeds_like_the_simulated_cell():
    from feeder_bt.run import RunOptions, run_job
    opts = dict(scenario="scenarios/lenses.yaml", duration=120.0, seed=1, view="none", db=None)
    emulated = run_job(RunOptions(hal="emulated", cell=CELL, **opts))
    simulated = run_job(RunOptions(hal="sim", fast=True, **opts))
    assert emulated["hal"] == "emulated" and emulated["state"] == "STOPPED"
    assert emulated["parts"]["lost"] == 0
    got, want = emulated["parts_per_minute"], simulated["parts_per_minute"]
    assert want > 20
    assert abs(got - want) <= 0.25 * want, (got, want)
