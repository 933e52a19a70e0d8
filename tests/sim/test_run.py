"""Whole runs on the simulated cell, in virtual time with fixed seeds."""

from __future__ import annotations

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import SimClock
from feeder_bt.sim.devices import make_sim_hal


def run(scenario: str, duration: float, seed: int = 1, **kw) -> dict:
    return run_job(RunOptions(scenario=scenario, duration=duration, fast=True, seed=seed,
                              view="none", **kw))


def key_counts(report: dict) -> tuple:
    p = report["parts"]
    return (p["retrieved"], p["located"], p["missed"], p["too_far"], p["recirculated"],
            report["vision"]["frames"], report["world"]["census"])


@pytest.fixture(scope="module")
def lenses_300():
    return run("scenarios/lenses.yaml", 300.0, seed=1)


def test_lenses_feed_and_nothing_is_lost(lenses_300):
    r = lenses_300
    assert r["state"] == "STOPPED" and r["fault"] is None
    assert r["parts"]["lost"] == 0
    assert r["parts"]["retrieved"]["lens"] > 150          # > 30/min over 5 minutes
    assert r["parts"]["located"] >= r["parts"]["retrieved"]["lens"]
    assert r["world"]["placed"]["lens"] == r["parts"]["retrieved"]["lens"]
    assert r["vision"]["frames"] > 50
    for key in ("p50_ms", "p99_ms", "max_ms", "overruns", "hz"):
        assert key in r["tick"]


def test_same_seed_same_counts(lenses_300):
    again = run("scenarios/lenses.yaml", 300.0, seed=1)
    assert key_counts(again) == key_counts(lenses_300)


def test_other_seed_other_counts(lenses_300):
    other = run("scenarios/lenses.yaml", 300.0, seed=2)
    assert key_counts(other) != key_counts(lenses_300)


def test_skipping_idle_ticks_changes_nothing():
    skipped = run("scenarios/lenses.yaml", 90.0, seed=4)
    every = run("scenarios/lenses.yaml", 90.0, seed=4, skip_idle=False)
    assert skipped["tick"]["skipped"] > 0 and every["tick"]["skipped"] == 0
    assert key_counts(skipped) == key_counts(every)


def test_squares_are_placed_in_orientation():
    r = run("scenarios/squares.yaml", 300.0, seed=2)
    assert r["parts"]["retrieved"]["square"] > 50
    assert r["parts"]["misoriented"] == 0
    assert r["parts"]["lost"] == 0


def test_mixed_scenario_retrieves_both_types():
    r = run("scenarios/lenses_and_squares.yaml", 300.0, seed=3)
    assert r["parts"]["retrieved"]["lens"] > 10
    assert r["parts"]["retrieved"]["square"] > 10
    assert r["parts"]["misoriented"] == 0
    assert r["parts"]["lost"] == 0


def _cell(path: str, seed: int = 1) -> tuple[Cell, Ticker]:
    scenario, spec = load_scenario(path)
    clock = SimClock()
    cell = Cell(spec, make_sim_hal(scenario, spec, clock, seed), clock)
    cell.load(scenario)
    return cell, Ticker(cell, fast=True)


def test_stop_while_waiting_on_an_empty_queue_is_prompt():
    cell, ticker = _cell("scenarios/lenses.yaml")
    cell.start()
    ticker.run(until=8.0)                       # set-up done, no part has reached the camera
    assert cell.state is CellState.RUNNING
    assert len(cell.ctx.queue) == 0
    waiting = [n for n in cell.nodes() if n.name == "next part"][0]
    assert waiting.status.name == "RUNNING"
    t_stop = cell.clock.now()
    cell.stop()
    ticker.run(until=t_stop + 5.0, stop=lambda: cell.state is CellState.STOPPED)
    assert cell.state is CellState.STOPPED
    assert cell.clock.now() - t_stop <= 1.0
    assert cell.hal.io.get("backlight") is False
    cell.hal.close()


def test_switch_scenario_without_restarting():
    cell, ticker = _cell("scenarios/lenses.yaml")
    cell.start()
    ticker.run(until=90.0)
    assert cell.stats.retrieved["lens"] > 0
    cell.stop()
    ticker.run(until=cell.clock.now() + 10.0, stop=lambda: cell.state is CellState.STOPPED)
    assert cell.state is CellState.STOPPED
    squares, _ = load_scenario("scenarios/squares.yaml")
    cell.load(squares)
    cell.start()
    t0 = cell.clock.now()
    ticker.run(until=t0 + 120.0)
    assert cell.state is CellState.RUNNING
    assert cell.stats.retrieved["square"] > 0
    assert "lens" not in cell.stats.retrieved
    assert cell.hal.world.lost() == 0
    cell.stop()
    ticker.run(until=cell.clock.now() + 10.0, stop=lambda: cell.state is CellState.STOPPED)
    assert cell.state is CellState.STOPPED
    cell.hal.close()
