"""A fast run with every kind of fault injected (``feeder run --faults``): each fault is
counted, recovered or reported as a FAULT, and no part is lost."""

from __future__ import annotations

import json
import sqlite3

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main

PLAN = """\
seed: 5
rates:
  servo_timeout: {per_pick: 0.01}
  comms_lost: {per_hour: 8, device: alternate, outage_s: 2.0}
  grab_failed: {per_frame: 0.004}
scripted:
  - {at_s: 1200, kind: conveyor_jam}
  - {at_s: 500, kind: estop, release_after_s: 20}
  - {at_s: 900, kind: comms_lost, device: camera, outage_s: 3.0}   # longer than a frame's spacing
"""


def test_every_injected_fault_is_counted_and_recovered(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text(PLAN)
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", duration=1800.0, fast=True,
                           seed=4, view="none", faults=str(plan)))
    assert r["state"] == "STOPPED", r["fault"]
    assert r["parts"]["lost"] == 0
    injected, faults, recovered = r["injected"], r["faults"], r["recoveries"]
    for kind in ("servo_timeout", "comms_lost", "grab_failed", "estop"):
        assert injected.get(kind, 0) >= 1, (kind, injected)
    # each injected fault was met by a branch (a link drop may strike two branches) ...
    for kind in ("servo_timeout", "comms_lost", "grab_failed", "estop"):
        assert faults.get(kind, 0) >= injected[kind], (kind, faults, injected)
    # ... and every fault the trees met was recovered: none ended in FAULT
    for kind in ("servo_timeout", "comms_lost", "grab_failed", "estop"):
        assert recovered.get(kind, 0) == faults[kind], (kind, faults, recovered)
    assert recovered.get("conveyor", 0) == faults.get("conveyor", 0) == injected.get(
        "conveyor_jam", 0) + r["watchdog_stops"]
    assert r["parts_per_minute"] > 55


@pytest.mark.parametrize("outage_s, stops", [(2.5, 1), (0.8, 0)])
def test_a_galil_outage_longer_than_the_watchdog_stops_the_belts_and_is_recovered(
        tmp_path, outage_s, stops):
    """The card's watchdog (galil.watchdog_s, 1 s) stops the belts in a longer outage: the
    present tree meets it once the link is back and starts them again."""
    plan = tmp_path / "plan.yaml"
    plan.write_text(f"scripted:\n  - {{at_s: 60, kind: comms_lost, device: galil, "
                    f"outage_s: {outage_s}}}\n")
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", duration=120.0, fast=True,
                           seed=1, view="none", faults=str(plan), db=str(tmp_path / "e.db")))
    assert r["state"] == "STOPPED" and r["parts"]["lost"] == 0
    assert r["watchdog_stops"] == stops
    assert r["faults"].get("conveyor", 0) == r["recoveries"].get("conveyor", 0) == stops
    assert r["recoveries"]["comms_lost"] == r["faults"]["comms_lost"] >= 1
    if stops:                                       # the speeds commanded again, after
        with sqlite3.connect(tmp_path / "e.db") as db:
            speeds = [t for (t,) in db.execute("SELECT t FROM events WHERE kind = 'speeds'")]
        assert any(60 + outage_s <= t < 70 for t in speeds)


def test_a_bad_plan_is_one_line_and_exit_2(tmp_path, capsys):
    plan = tmp_path / "plan.yaml"
    plan.write_text("rates:\n  servo_timeout: {per_frame: 0.1}\n")
    code = main(["run", "scenarios/lenses.yaml", "--fast", "--duration", "10", "--no-db",
                 "--faults", str(plan)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "plan.yaml:2" in err[0]


def test_report_names_the_plan(tmp_path):
    plan = tmp_path / "plan.yaml"
    plan.write_text("rates:\n  grab_failed: {per_frame: 0.05}\n")
    out = tmp_path / "r.json"
    assert main(["run", "scenarios/lenses.yaml", "--fast", "--duration", "120", "--no-db",
                 "--view", "none", "--faults", str(plan), "--report", str(out)]) == 0
    r = json.loads(out.read_text())
    assert r["fault_plan"].endswith("plan.yaml")
    assert r["injected"]["grab_failed"] >= 1


def test_a_robot_that_misses_every_pick_stops_the_cell(tmp_path):
    """A wrong frame or a gripper without vacuum: every pick misses. Each is counted and the
    part recirculates; at retrieve.max_failed_picks (20) in a row the cell calls the
    operator, naming what to check."""
    plan = tmp_path / "plan.yaml"
    plan.write_text("rates:\n  missed_grab: {per_pick: 1.0}\n")
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", duration=600.0, fast=True,
                           seed=2, view="none", faults=str(plan)))
    assert r["state"] == "FAULT" and "robot frame" in r["fault"], r["fault"]
    assert r["parts"]["missed"] == 20 and r["parts"]["lost"] == 0
    assert sum(r["parts"]["retrieved"].values()) == 0


def test_misses_now_and_then_never_stop_the_cell(tmp_path):
    """One pick in three missed, for half an hour: never twenty in a row, never a FAULT."""
    plan = tmp_path / "plan.yaml"
    plan.write_text("seed: 3\nrates:\n  missed_grab: {per_pick: 0.33}\n")
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", duration=1800.0, fast=True,
                           seed=3, view="none", faults=str(plan)))
    assert r["state"] == "STOPPED", r["fault"]
    assert r["parts"]["missed"] >= 300 and r["parts"]["lost"] == 0
