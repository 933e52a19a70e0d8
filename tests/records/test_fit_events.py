"""What a twin's fit reads from the event log: frames with their rejected blobs, timed
picks and places (a real cell's log has the same; tuning/twin.py reads them)."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from feeder_bt.app.run import RunOptions, run_job

LENSES = str(Path(__file__).resolve().parents[2] / "scenarios/lenses.yaml")
PLATE = str(Path(__file__).resolve().parents[2] / "scenarios/plate_lenses.yaml")


def test_frames_picks_and_places_are_logged(tmp_path: Path) -> None:
    db = tmp_path / "run.db"
    r = run_job(RunOptions(scenario=LENSES, duration=90.0, fast=True, seed=2, view="none",
                           db=str(db)))
    with sqlite3.connect(db) as conn:
        ev = [(t, k, json.loads(d)) for t, k, d in conn.execute(
            "SELECT t, kind, data FROM events WHERE kind IN ('frame', 'pick', 'place')")]
    frames = [d for _, k, d in ev if k == "frame"]
    picks = [d for _, k, d in ev if k == "pick"]
    places = [d for _, k, d in ev if k == "place"]
    # every new part located is in a frame's count; every placed part had a timed place
    assert sum(f["new"] for f in frames) == r["parts"]["located"]
    # a place the run's stop cut short still counts, but is no timed move
    retrieved = sum(r["parts"]["retrieved"].values())
    assert retrieved - 1 <= len(places) <= retrieved
    assert sum(p["outcome"] == "held" for p in picks) >= len(places)
    assert sum(p["outcome"] == "missed_grab" for p in picks) == r["parts"]["missed"]
    assert all(0.2 < p["dt"] < 3.0 for p in places)
    reasons = {b[0] for f in frames for b in f["rejected"]}
    assert reasons and all(";" not in w and "(" not in w for w in reasons)


def test_plate_actions_are_logged_with_their_times(tmp_path: Path) -> None:
    """A plate cell's log times each action from its command to the feeder's done, and
    each frame says how many parts were pickable and where the blobs sat along the feed
    (what a plate twin's fit reads, tuning/twin_plate.py)."""
    from feeder_bt.config import load_scenario
    db = tmp_path / "plate.db"
    r = run_job(RunOptions(scenario=PLATE, duration=90.0, fast=True, seed=2, view="none",
                           db=str(db)))
    plate = load_scenario(PLATE)[1].plate
    with sqlite3.connect(db) as conn:
        ev = [(k, json.loads(d)) for k, d in conn.execute(
            "SELECT kind, data FROM events WHERE kind IN ('plate', 'plate_done', 'frame') "
            "ORDER BY t")]
    started = [d for k, d in ev if k == "plate"]
    done = [d for k, d in ev if k == "plate_done"]
    assert done and len(started) - 1 <= len(done) <= len(started)
    for d in done:           # the feeder's time, seen at the next 5 ms tick
        reps = d["reps"] + (d["action"] == "flip_forward")
        assert d["dt"] == pytest.approx(reps * plate.rep_s + plate.settle_s, abs=0.011)
    frames = [d for k, d in ev if k == "frame"]
    assert sum(f["new"] for f in frames) == r["parts"]["located"]
    assert all(0 <= f["pickable"] <= f["parts"] for f in frames)
    assert any(f["x_mm"] is not None for f in frames)
