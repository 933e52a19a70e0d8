"""Two cells in one process: each has its own blackboard and its own ticker news, so
ticked in turn they count exactly what each counts alone."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.analysis.report import build_report
from feeder_bt.app.factory import make_hal
from feeder_bt.behaviours.keys import SPEEDS
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker

ROOT = Path(__file__).resolve().parents[2]
DURATION_S = 180.0          # simulated seconds each
TURN_S = 0.5                # the cells take turns this much simulated time at a time
JOBS = (("lenses", 1), ("squares", 2))


class Run:
    """One cell on its own simulated world and SimClock, ticked fast."""

    def __init__(self, name: str, seed: int) -> None:
        self.scenario, spec = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
        hal, clock = make_hal("sim", self.scenario, spec, seed)
        self.seed = seed
        self.cell = Cell(spec, hal, clock)
        self.cell.load(self.scenario)
        self.cell.start()
        self.ticker = Ticker(self.cell, fast=True)

    def turn(self, until: float) -> None:
        self.ticker.run(until=until)

    def counts(self) -> dict:
        """The report's counts (no wall-clock figures) and the ticker's ticks."""
        cell, t = self.cell, self.cell.clock.now()
        r = build_report(cell, self.ticker, seed=self.seed, hal="sim", sim_seconds=t,
                         feed_seconds=t, wall_seconds=0.0).to_json()
        ticks = self.ticker.stats
        out = {"parts": r["parts"], "world": r["world"], "frames": r["vision"]["frames"],
               "faults": r["faults"], "state": cell.state.value, "speeds": cell.speeds(),
               "ticks": (ticks.ticks, ticks.skipped)}
        if cell.ctx is not None and cell.ctx.vision is not None:
            cell.ctx.vision.close()
        return out


def take_turns(runs: list[Run]) -> None:
    t = 0.0
    while t < DURATION_S:
        t = min(DURATION_S, t + TURN_S)
        for run in runs:
            run.turn(t)


@pytest.fixture(scope="module")
def alone() -> list[dict]:
    out = []
    for name, seed in JOBS:
        run = Run(name, seed)
        take_turns([run])
        out.append(run.counts())
    return out


def test_two_cells_ticked_in_turn_count_what_each_counts_alone(alone) -> None:
    runs = [Run(name, seed) for name, seed in JOBS]
    take_turns(runs)
    together = [run.counts() for run in runs]
    for one, other in zip(alone, together, strict=True):
        assert one["state"] == "RUNNING" and sum(one["parts"]["retrieved"].values()) > 50
        assert other == one


def test_a_cells_board_is_its_own() -> None:
    runs = [Run("lenses", 1), Run("lenses", 2)]
    try:
        runs[0].cell.set_speeds(horizontal_mm_s=123.0)
        assert runs[0].cell.speeds()["horizontal_mm_s"] == 123.0
        assert runs[1].cell.board.get(SPEEDS.HORIZONTAL) == runs[1].scenario.present.horizontal_mm_s
        assert runs[1].cell.state is CellState.STARTING
    finally:
        for run in runs:
            run.counts()
