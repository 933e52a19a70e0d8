"""The emulated cell (``--hal emulated``) with its camera through pypylon and Basler's camera
emulator: each frame is the plant's belt at the pulse the Galil emulator latched, and the
whole run feeds like the simulated cell (a soak run: real time)."""

from __future__ import annotations

import numpy as np
import pytest

from feeder_bt.config.loader import load_scenario
from tests.support.galil_fixtures import wait_job, wait_until

pytest.importorskip("pypylon", reason="pypylon is not installed (pip install -e '.[pylon]')")

CELL = "cells/sim_pylon.yaml"


@pytest.fixture(autouse=True)
def camemu(monkeypatch):
    monkeypatch.setenv("PYLON_CAMEMU", "1")


@pytest.mark.parametrize("trigger", ["Line1", "Software"])
def test_emulated_cell_frames_come_through_pylon_paired_with_the_galil_latch(trigger):
    from feeder_bt.app.factory import start_emulated
    sc, cell = load_scenario("scenarios/lenses.yaml", cell=CELL)
    assert cell.camera.source == "pylon:" and cell.camera.pylon.trigger == "Line1"
    cell.camera.pylon.trigger = trigger      # Line1: bridged at the Galil pulse
    cell.camera.pylon.frame_timeout_s = 10.0   # generous: a loaded machine
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
        assert bridge.source.cam.TriggerSource.Value == trigger
    finally:
        hal.close()


def test_a_pylon_cell_without_a_camera_is_a_one_line_error(monkeypatch):
    from feeder_bt.app.factory import start_emulated
    from feeder_bt.core.errors import ConfigError
    monkeypatch.setenv("PYLON_CAMEMU", "0")
    sc, cell = load_scenario("scenarios/lenses.yaml", cell=CELL)
    with pytest.raises(ConfigError, match=r"camera.source: pylon:: no such pylon camera "
                                          r"\(cameras found: none; PYLON_CAMEMU=N adds"):
        start_emulated(sc, cell, seed=3)


@pytest.mark.soak          # real time: two minutes of wall clock through the TCP drivers
def test_pylon_emulated_run_feeds_like_the_simulated_cell():
    from feeder_bt.app.run import RunOptions, run_job
    opts = dict(scenario="scenarios/lenses.yaml", duration=120.0, seed=1, view="none", db=None)
    emulated = run_job(RunOptions(hal="emulated", cell=CELL, **opts))
    simulated = run_job(RunOptions(hal="sim", fast=True, **opts))
    assert emulated["hal"] == "emulated" and emulated["state"] == "STOPPED"
    assert emulated["parts"]["lost"] == 0
    cam = emulated["camera"]                      # every frame came through pylon, paired
    assert cam["frames"] >= emulated["vision"]["frames"] > 50
    assert cam["lost_frames"] == 0 and cam["extra_triggers"] == 0
    got, want = emulated["parts_per_minute"], simulated["parts_per_minute"]
    assert want > 20
    assert abs(got - want) <= 0.25 * want, (got, want)


def test_injected_camera_faults_are_one_line_each_and_never_mis_paired():
    """Fault injection at the camera (emulators.faults, controller "camera"): it disappears,
    a trigger brings no frame, a second pulse comes on the wire, the pixel format is
    changed behind the cell's back. Each costs one grab with one line; every frame that
    is delivered is the image of the very pulse whose count the Galil latched."""
    from feeder_bt.app.factory import start_emulated
    from feeder_bt.emulators.faults import FaultPlan
    plan = FaultPlan()
    # a rule counts the triggers no earlier rule fired on: at triggers 2, 4, 6 and 8
    for nth, kind in ((2, "drop"), (3, "no_frame"), (4, "extra_trigger"), (5, "wrong_format")):
        plan.add(kind, "camera", "TRIGGER", nth=nth)
    sc, cell = load_scenario("scenarios/lenses.yaml", cell=CELL)
    cell.camera.pylon.frame_timeout_s = 10.0   # generous: a loaded machine
    hal, _clock = start_emulated(sc, cell, seed=3, faults=plan)
    try:
        bridge = hal.camera.source
        galil = hal.extras["galil_emulator"]
        pulses: list[tuple[int, np.ndarray | None]] = []     # (count at the pulse, image)
        hal.extras["plant"].on_trigger(
            lambda t: pulses.append((int(round(galil._measured("B", t))), None)))
        write = bridge.files.write

        def keep(img):
            pulses[-1] = (pulses[-1][0], img.copy())
            write(img)
        bridge.files.write = keep
        belt = hal.conveyors["horizontal"]
        hal.motors_on()
        assert wait_job(belt.set_speed(100.0), 30).ok
        errors, frames = [], []
        for _ in range(10):
            was = belt.position()
            assert wait_until(lambda was=was: belt.position() > was + 40, 30)
            job = wait_job(hal.camera.grab(), 30)
            assert job.done
            if job.ok:
                frames.append(job.result)
            else:
                errors.append(str(job.error))
        assert len(errors) == 3, (errors, plan.log, bridge.counts())  # drop, no_frame, wrong_format
        assert all("\n" not in e for e in errors)
        assert "the camera is gone" in errors[0] and "reopened" in errors[0]
        assert "lost: The buffer was incompletely grabbed" in errors[1]
        assert "pixel format Mono16, the cell expects Mono8" in errors[2]
        assert bridge.counts()["extra_triggers"] == 1
        assert len(frames) == 7
        for f in frames:                          # never mis-paired
            match = [count for count, img in pulses
                     if img is not None and np.array_equal(img, f.image)]
            assert match == [f.latch], (f.latch, match)
        assert [k for _, k, _ in plan.log] == ["drop", "no_frame", "extra_trigger",
                                               "wrong_format"]
    finally:
        hal.close()


def _run_with_camera_dropped(monkeypatch, unplugged: bool) -> dict:
    """A 20 s emulated run whose camera is closed at the fifth trigger; ``unplugged``: and
    no longer enumerated after that (PYLON_CAMEMU=0), so it cannot be opened again."""
    from feeder_bt.app import run as run_mod
    from feeder_bt.app.factory import start_emulated
    from feeder_bt.app.run import RunOptions, run_job
    from feeder_bt.emulators import pylon_camera
    from feeder_bt.emulators.faults import FaultPlan
    inject = pylon_camera.PylonPlantCamera._inject

    def inject_and_unplug(self, kind):
        inject(self, kind)
        if unplugged:
            monkeypatch.setenv("PYLON_CAMEMU", "0")
    monkeypatch.setattr(pylon_camera.PylonPlantCamera, "_inject", inject_and_unplug)
    plan = FaultPlan()
    plan.add("drop", "camera", "TRIGGER", nth=5)
    monkeypatch.setattr(run_mod, "make_hal", lambda kind, scenario, cell, seed, world=None:
                        start_emulated(scenario, cell, seed, faults=plan))
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", hal="emulated", duration=20.0,
                           seed=1, view="none", db=None, cell=CELL))
    assert len(plan.log) == 1
    return r


@pytest.mark.soak          # real time: 20 s through the TCP drivers
def test_a_camera_closed_mid_run_is_reopened_and_feeding_goes_on(monkeypatch):
    r = _run_with_camera_dropped(monkeypatch, unplugged=False)
    assert r["state"] == "STOPPED", r["fault"]
    assert r["faults"] == {"grab_failed": 1} and r["recoveries"] == {"grab_failed": 1}
    assert r["camera"]["lost_frames"] == 1 and r["camera"]["frames"] > 5
    assert r["parts"]["lost"] == 0


@pytest.mark.soak          # real time: up to 20 s through the TCP drivers
def test_a_camera_unplugged_mid_run_faults_the_cell_with_one_line(monkeypatch):
    r = _run_with_camera_dropped(monkeypatch, unplugged=True)
    assert r["state"] == "FAULT"
    assert r["fault"].startswith("camera or vision failed: camera pylon:: the camera is gone")
    assert "no such pylon camera (cameras found: none" in r["fault"] and "\n" not in r["fault"]
    assert r["parts"]["lost"] == 0
