"""Helpers for the V+ interpreter tests: run V+ text on a runtime over a (not stepped)
plant, on the test's own thread."""

from __future__ import annotations

import functools

from feeder_bt.config import load_scenario
from feeder_bt.emulators.vplus.program import load_text
from feeder_bt.emulators.vplus.runtime import Runtime
from feeder_bt.emulators.vplus.task import Cell, Task
from feeder_bt.emulators.vplus.trans import Trans
from feeder_bt.sim.realtime import Plant


@functools.lru_cache(maxsize=1)
def _scenario():
    return load_scenario("scenarios/lenses.yaml")


def make_runtime(text: str, plant: Plant | None = None) -> Runtime:
    scenario, cell = _scenario()
    plant = plant or Plant(scenario, cell, seed=1)
    programs = {p.name: p for p in load_text(text, "test.v2")}
    bx, by = cell.robot.base_mm
    return Runtime(programs, plant, Trans.make(bx, by, 0.0, cell.robot.base_deg), {})


def run(text: str, main: str = "main", args: tuple = (), rt: Runtime | None = None
        ) -> tuple[Runtime, list[Cell]]:
    """Run ``main`` to its end on task 0; returns the runtime and the argument cells."""
    rt = rt or make_runtime(text)
    task = rt.tasks.setdefault(0, Task(rt, 0))
    rt.arm.owner = task
    cells = [Cell(a) for a in args]
    task.call(main, cells)
    return rt, cells


def g(rt: Runtime, name: str):
    """A global's value."""
    return rt.globals[name].v
