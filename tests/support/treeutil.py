"""Helpers for tick-level tree tests over the mock HAL and a hand-advanced SimClock."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Access

from feeder_bt.behaviours.base import Ctx, Stats, init_blackboard
from feeder_bt.config import load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.encoder import EncoderSync
from feeder_bt.core.parts import Part, PartsQueue
from feeder_bt.hal.interfaces import Frame
from feeder_bt.hal.mock.hal import MockHal, MockJob
from feeder_bt.policy.adjusters import make_adjuster

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = ROOT / "scenarios"
DT = 0.02      # 50 Hz


def scenario(name: str = "lenses"):
    """``(scenario, cell)`` loaded fresh from ``scenarios/<name>.yaml``."""
    return load_scenario(SCENARIOS / f"{name}.yaml")


class FakeVision:
    """Stands in for the VisionWorker: every ``recognise`` is a MockJob the test finishes."""

    def __init__(self) -> None:
        self.jobs: list[MockJob] = []
        self.golden: np.ndarray | None = None

    def recognise(self, image: np.ndarray) -> MockJob:
        job = MockJob("vision.recognise", (image,))
        self.jobs.append(job)
        return job

    def set_golden(self, image: np.ndarray) -> None:
        self.golden = image

    def close(self) -> None:
        pass


def make_ctx(scen=None, cell=None, **scenario_changes: Any) -> Ctx:
    """A Ctx over a fresh MockHal and SimClock(0); the blackboard is reset for the scenario.

    ``scenario_changes`` are ``section=dict`` pairs applied with ``dataclasses.replace``,
    e.g. ``present={"mode": "incremental"}``.
    """
    if scen is None:
        scen, cell = scenario()
    for section, fields in scenario_changes.items():
        scen = dataclasses.replace(
            scen, **{section: dataclasses.replace(getattr(scen, section), **fields)})
    init_blackboard(scen)
    hal = MockHal()
    clock = SimClock()
    return Ctx(hal=hal, clock=clock, scenario=scen, cell=cell,
               queue=PartsQueue(list(scen.parts)),
               encoder=EncoderSync(cell.encoder.conveyor_bits, cell.encoder.robot_bits),
               stats=Stats(), vision=FakeVision(),
               adjuster=make_adjuster(scen.adjust.algorithm, scen.adjust.params))


def tick(root: py_trees.behaviour.Behaviour, ctx: Ctx | None = None, n: int = 1,
         dt: float = DT) -> py_trees.common.Status:
    """Tick ``root`` ``n`` times, advancing the clock ``dt`` after each tick."""
    for _ in range(n):
        root.tick_once()
        if ctx is not None:
            ctx.clock.advance(dt)
    return root.status


def pending(hal: MockHal, device: str, method: str) -> MockJob:
    """The one RUNNING job of ``device.method`` (fails the test if there is not exactly one)."""
    jobs = hal.pending(device, method)
    assert len(jobs) == 1, f"expected one pending {device}.{method}, got {jobs}; calls {hal.calls}"
    return jobs[0]


def finish(hal: MockHal, device: str, method: str, result: Any = None) -> MockJob:
    """Succeed the pending job of ``device.method``."""
    job = pending(hal, device, method)
    job.succeed(result)
    return job


def fail(hal: MockHal, device: str, method: str, error: Exception) -> MockJob:
    job = pending(hal, device, method)
    job.fail(error)
    return job


def bb_get(key: str) -> Any:
    return py_trees.blackboard.Blackboard.get(key)


def bb_set(key: str, value: Any) -> None:
    client = py_trees.blackboard.Client(name="test")
    client.register_key(key=key, access=Access.WRITE)
    client.set(key, value)


def frame(latch: int, t: float = 0.0, index: int = 1) -> Frame:
    return Frame(image=np.zeros((484, 640), np.uint8), latch=latch, t=t, index=index)


def detection(x_mm: float, y_mm: float, angle_deg: float = 0.0, part: str = "lens",
              pose: str = "flat", pickable: bool = True, **features: float) -> SimpleNamespace:
    return SimpleNamespace(part=part, pose=pose, pickable=pickable, x_mm=x_mm, y_mm=y_mm,
                           angle_deg=angle_deg, features=features or {"area_mm2": 2027.0})


def result(*parts: SimpleNamespace, rejected: tuple = (), ms: float = 4.0) -> SimpleNamespace:
    return SimpleNamespace(parts=list(parts), rejected=list(rejected), ms=ms)


_ids = iter(range(10_000, 10**9))


def part(x_mm: float, y_mm: float = 0.0, latch: int = 0, located_at: float = 0.0,
         type: str = "lens", angle_deg: float = 0.0) -> Part:
    return Part(id=next(_ids), type=type, x_mm=x_mm, y_mm=y_mm, angle_deg=angle_deg,
                latch=latch, located_at=located_at, pose="flat")


def ideal_cell(dest: Path, cell: str = "cells/sim.yaml") -> str:
    """A copy of ``cell`` with the simulator's imperfections off (``sim: {ideal: true}``),
    for tests whose subject is not the simulator and that need its ideal timing."""
    src = Path(__file__).resolve().parents[2] / cell
    out = Path(dest) / f"ideal_{Path(cell).name}"
    out.write_text(src.read_text() + "\nsim: {ideal: true}\n")
    return str(out)
