"""The main job through the real Galil and V+ drivers, against the emulators on loopback
(``--hal emulated``): it feeds like the simulated cell, and keeps feeding when the
controllers' connections are cut. These run in real time; the ten-minute cable pull is a
soak run (``python -m pytest -m soak``)."""

from __future__ import annotations

import threading

import pytest

import feeder_bt.app.run as run_mod
from feeder_bt.app.run import RunOptions, run_job


def _capture_hal(monkeypatch) -> dict:
    seen: dict = {}
    real = run_mod.make_hal

    def make_hal(*args, **kw):
        hal, clock = real(*args, **kw)
        seen["hal"] = hal
        return hal, clock

    monkeypatch.setattr(run_mod, "make_hal", make_hal)
    return seen


@pytest.mark.soak          # real time: 40 s of wall clock through the TCP drivers
def test_emulated_run_feeds_like_the_simulated_cell():
    opts = dict(scenario="scenarios/lenses.yaml", duration=45.0, seed=1, view="none", db=None)
    emulated = run_job(RunOptions(hal="emulated", **opts))
    simulated = run_job(RunOptions(hal="sim", fast=True, **opts))
    assert emulated["hal"] == "emulated" and emulated["state"] == "STOPPED"
    assert emulated["parts"]["lost"] == 0
    assert emulated["parts"]["missed"] <= 2
    got, want = emulated["parts_per_minute"], simulated["parts_per_minute"]
    assert want > 20
    assert abs(got - want) <= 0.25 * want, (got, want)


@pytest.mark.soak
def test_cut_connections_are_survived_without_losing_a_part(monkeypatch):
    """Ten minutes; every 75 s the test cuts the Galil's or the Adept's TCP connections
    from the server side (a pulled cable). Feeding goes on after each cut."""
    seen = _capture_hal(monkeypatch)
    cuts: list[tuple[str, int]] = []
    after: list[int] = []
    stop = threading.Event()

    def placed() -> int:
        world = seen["hal"].extras["plant"].world
        return sum(world.placed_by_type.values())

    def cutter() -> None:
        while "hal" not in seen and not stop.wait(0.1):
            pass
        which = ["galil_emulator", "adept_emulator"]
        i = 0
        while not stop.wait(75.0):
            emulator = seen["hal"].extras[which[i % 2]]
            if cuts:
                after.append(placed())
            cuts.append((which[i % 2], placed()))
            emulator.drop_clients()
            i += 1

    t = threading.Thread(target=cutter, daemon=True)
    t.start()
    try:
        report = run_job(RunOptions(scenario="scenarios/lenses.yaml", hal="emulated",
                                    duration=600.0, seed=2, view="none", db=None))
    finally:
        stop.set()
        t.join(timeout=5)
    assert len(cuts) >= 7
    assert {name for name, _ in cuts} == {"galil_emulator", "adept_emulator"}
    # between one cut and the next, parts were placed: feeding resumed after every cut
    for (_, before), now in zip(cuts, after, strict=False):
        assert now > before + 10, (cuts, after)
    assert report["state"] == "STOPPED", report["fault"]
    assert report["parts"]["lost"] == 0
    assert report["parts_per_minute"] > 30
