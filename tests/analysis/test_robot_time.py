"""Where the arm's time went (the report's ``robot_time``, ``RobotFit.time_split``): on
pick-and-place cycles, waiting at the reach for a part still upstream, on picks that
gripped nothing, idle. Counted from the controller's own timings, so a real cell reports
it too; the simulated world's truth of the waits (``world.pick_waited_s``) checks it."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config.loader import load_cell
from feeder_bt.policy.supply_bound import transport_lag_s

ROOT = Path(__file__).resolve().parents[2]
# fast belts (a fixed setting within the cell's limits); starved: 30 lenses at the start and
# a tote of 30 at 20 s, placed parts shipped; closed loop: 150 lenses going round
FAST = "present: {horizontal_mm_s: 337.4, incline_pct: 113.1}\nadjust: {algorithm: none}\n"
STARVED = "start: {lens: 30}\nship_placed: true\ntotes: {first_at_s: 20, every_s: 1000, parts: 30}\n"
MISSES = "seed: 1\nrates:\n  missed_grab: {per_pick: 0.3}\n"
ESTOP = "scripted:\n  - {at_s: 60, kind: estop, release_after_s: 10}\n"


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, dict]:
    d = tmp_path_factory.mktemp("robot_time")
    for name, text in (("fast", FAST), ("starved", STARVED), ("misses", MISSES),
                       ("estop", ESTOP)):
        (d / f"{name}.yaml").write_text(text)

    def run(duration: float, **kw: str) -> dict:
        return run_job(RunOptions(scenario=str(ROOT / "scenarios/lenses.yaml"), fast=True,
                                  seed=1, view="none", duration=duration,
                                  overlay=str(d / "fast.yaml"), **kw))

    return {"starved": run(120.0, supply=str(d / "starved.yaml")),
            "full": run(150.0),
            "misses": run(150.0, faults=str(d / "misses.yaml")),
            "estop": run(150.0, faults=str(d / "estop.yaml"))}


def test_the_split_adds_up_to_the_feeding_time(runs):
    """And counts the whole run: a restart (after the e-stop) keeps the arm's account, as
    it keeps the parts' (each placed part's cycle is at least the robot bound's)."""
    assert runs["estop"]["recoveries"].get("estop") == 1
    for r in runs.values():
        rt = r["robot_time"]
        placed = sum(r["parts"]["retrieved"].values())
        assert rt["cycles_pct"] / 100 * r["feed_seconds"] >= placed * r["robot_bound_cycle_s"]
        assert rt["cycles_pct"] + rt["waiting_pct"] == pytest.approx(r["robot_busy_pct"],
                                                                     abs=0.15)
        assert sum(rt[k] for k in ("cycles_pct", "waiting_pct", "missed_pct", "idle_pct")) \
            == pytest.approx(100.0, abs=0.25)


def test_the_waits_agree_with_the_worlds_truth(runs):
    """The controller prices each wait with its learnt model of the arm, which is short on
    the SCARA's moves to the reach's edge: so the estimate reads a little high,
    never low, and within a quarter of the truth (plus 0.2 points of feeding)."""
    for r in runs.values():
        truth = 100.0 * r["world"]["pick_waited_s"] / r["feed_seconds"]
        est = r["robot_time"]["waiting_pct"]
        assert truth - 0.1 <= est <= 1.25 * truth + 0.2, (est, truth)
    assert runs["starved"]["robot_time"]["waiting_pct"] > 8.0   # a case that can fail


def test_a_starved_robot_idles_and_waits_a_saturated_one_cycles(runs):
    starved, full = runs["starved"]["robot_time"], runs["full"]["robot_time"]
    assert starved["idle_pct"] > 30 and starved["waiting_pct"] > 8
    assert full["cycles_pct"] > 80 and full["idle_pct"] < 10 and full["waiting_pct"] < 3
    # no part reaches the robot before the shortest ride from the hopper
    lag = transport_lag_s(load_cell(ROOT / "cells/sim.yaml"))
    for r in runs.values():
        assert lag <= r["robot_time"]["first_pick_s"] < lag + 3.0


def test_missed_picks_cost_the_arm_a_pick_each(runs):
    """A grab that closes on nothing took the arm's time, and placed no part: it is
    counted apart, a pick's time for each miss."""
    full, misses = runs["full"], runs["misses"]
    assert misses["robot_time"]["missed_pct"] > full["robot_time"]["missed_pct"] + 10
    for r in (full, misses):
        n = r["misses"]["missed_grab"]
        each = r["robot_time"]["missed_pct"] / 100 * r["feed_seconds"] / n
        assert 0.25 < each < 0.9, each      # a pick's time (the cycle is 0.7-0.9 s)


def test_the_summary_says_it_in_80_columns(runs):
    for r in runs.values():           # two-figure shares in the starved and missing runs
        rt = r["robot_time"]
        line = next(ln for ln in summary(r).splitlines() if ln.startswith("  robot: "))
        assert line == (f"  robot: cycles {rt['cycles_pct']:.1f} %, waiting for parts "
                        f"{rt['waiting_pct']:.1f} %, missed {rt['missed_pct']:.1f} %, "
                        f"idle {rt['idle_pct']:.1f} %")
        assert len(line) <= 80
