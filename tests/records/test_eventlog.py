"""The SQLite event log and `feeder report`: fixed seeds, virtual time, no wall-clock checks."""

from __future__ import annotations

import enum
import json
import re
import signal
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from feeder_bt.app import run as run_mod
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.behaviours.base import Stats
from feeder_bt.cli.main import main as cli_main
from feeder_bt.records.eventlog import EventLog, EventLogError, open_readonly
from feeder_bt.records.runs_db import rolling_ppm

LENSES = str(Path("scenarios/lenses.yaml").resolve())
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run(db: Path, duration: float = 120.0, seed: int = 3) -> dict:
    return run_job(RunOptions(scenario=LENSES, duration=duration, fast=True, seed=seed,
                              view="none", db=str(db)))


def rows(db: Path, sql: str, *args) -> list[tuple]:
    with sqlite3.connect(db) as conn:
        return conn.execute(sql, args).fetchall()


@pytest.fixture(scope="module")
def logged(tmp_path_factory):
    db = tmp_path_factory.mktemp("log") / "runs" / "feeder.db"     # folder created on demand
    return db, run(db)


def test_run_row_holds_meta_and_report(logged):
    db, report = logged
    (run_id, scenario, cell, seed, hal, started, ended, options, stored), = rows(
        db, "SELECT id, scenario, cell, seed, hal, started, ended, options, report FROM runs")
    assert (run_id, scenario, cell, seed, hal) == (1, "lenses", report["cell"], 3, "sim")
    assert started and ended
    opts = json.loads(options)
    assert opts["duration"] == 120.0 and opts["fast"] is True
    assert opts["adjust"]["algorithm"] == "water_marks"
    assert json.loads(stored)["parts"] == json.loads(json.dumps(report["parts"]))


def test_event_counts_match_the_report(logged):
    db, report = logged
    counts = dict(rows(db, "SELECT kind, count(*) FROM events WHERE run_id=1 GROUP BY kind"))
    total = sum(report["parts"]["retrieved"].values())
    assert total > 50
    assert counts["retrieved"] == total
    assert counts["located"] == report["parts"]["located"]
    by_type = dict(rows(db, "SELECT json_extract(data, '$.type'), count(*) FROM events "
                            "WHERE kind='retrieved' GROUP BY 1"))
    assert by_type == report["parts"]["retrieved"]
    states = [json.loads(d)["new"] for d, in rows(
        db, "SELECT data FROM events WHERE kind='state' ORDER BY rowid")]
    # the first switch happens on the Stats that Cell.start() creates: still logged
    assert states == ["STARTING", "RUNNING", "STOPPING", "STOPPED"]
    ts = [t for t, in rows(db, "SELECT t FROM events ORDER BY rowid")]
    assert 0.0 <= min(ts) and max(ts) <= report["sim_seconds"] + 1e-9


def test_samples_give_the_time_series(logged):
    db, report = logged
    samples = rows(db, "SELECT t, queue, horizontal_mm_s, incline_pct, robot_speed_pct, "
                       "retrieved FROM samples WHERE run_id=1 ORDER BY t")
    assert len(samples) > 200                          # every 0.5 s adjust period
    t = np.array([s[0] for s in samples])
    retrieved = np.array([s[5] for s in samples])
    assert np.all(np.diff(t) > 0) and np.all(np.diff(retrieved) >= 0)
    assert retrieved[-1] <= sum(report["parts"]["retrieved"].values())
    assert all(80.0 <= s[2] <= 200.0 for s in samples)  # the adjuster's limits


def test_report_prints_summary_and_json(logged, capsys):
    db, report = logged
    assert cli_main(["report", str(db)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:4] == ["run", "scenario", "seed", "state"]
    total = sum(report["parts"]["retrieved"].values())
    assert "lenses" in out[1] and f"lens {total}" in out[1] and "STOPPED" in out[1]
    assert cli_main(["report", str(db), "--last", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["retrieved"] == report["parts"]["retrieved"]
    assert summary["parts_per_minute"] == report["parts_per_minute"]
    assert summary["lost"] == 0


def test_plot_writes_png_with_labelled_axes(logged, tmp_path, capsys):
    db, _ = logged
    out = tmp_path / "plots" / "speeds.png"
    assert cli_main(["report", str(db), "--run", "1", "--plot", str(out)]) == 0
    data = out.read_bytes()
    assert data.startswith(PNG_MAGIC) and len(data) > 20_000
    from feeder_bt.cli.plots import plot_run
    conn = open_readonly(db)
    fig = plot_run(conn, 1)
    speed, queue, ppm = fig.axes
    assert [a.get_ylabel() for a in fig.axes] == ["speed (mm/s)", "queue (parts)", "parts/min"]
    assert ppm.get_xlabel() == "time (s)"
    samples = conn.execute("SELECT t, horizontal_mm_s, queue FROM samples ORDER BY t").fetchall()
    line = speed.get_lines()[0]
    assert list(line.get_xdata()) == [s[0] for s in samples]
    assert list(line.get_ydata()) == [s[1] for s in samples]
    assert list(queue.get_lines()[0].get_ydata()) == [s[2] for s in samples]
    rate = np.asarray(ppm.get_lines()[0].get_ydata())
    assert 20 < np.nanmax(rate) < 120
    for ax in fig.axes:
        assert ax.get_legend() is not None
    conn.close()


@pytest.mark.parametrize("content", [b"this is not a database\n" * 50, b""],
                         ids=["garbage", "empty"])
def test_corrupt_or_foreign_db_is_one_line_exit_2(tmp_path, content):
    bad = tmp_path / "bad.db"
    bad.write_bytes(content)
    p = subprocess.run([sys.executable, "-m", "feeder_bt.cli", "report", str(bad),
                        "--plot", str(tmp_path / "x.png")],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 2
    assert p.stderr.count("\n") == 1 and "Traceback" not in p.stderr
    assert p.stderr.startswith("feeder: ") and "bad.db" in p.stderr
    assert not (tmp_path / "x.png").exists()


def test_missing_and_foreign_db_and_unknown_run(tmp_path, logged, capsys):
    assert cli_main(["report", str(tmp_path / "none.db")]) == 2
    foreign = tmp_path / "foreign.db"
    with sqlite3.connect(foreign) as conn:
        conn.execute("CREATE TABLE x (a)")
    assert cli_main(["report", str(foreign)]) == 2
    with pytest.raises(EventLogError, match="not a feeder event log"):
        EventLog(foreign)                     # never writes into someone else's database
    assert cli_main(["report", str(logged[0]), "--run", "99"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all(line.startswith("feeder: ") for line in err)


def test_stop_request_flushes_the_buffer(tmp_path, monkeypatch):
    """Ctrl-C (an orderly stop) with nothing flushed yet: every buffered event still lands."""
    monkeypatch.setattr(EventLog, "periodic_flush", lambda self: None)

    class CtrlC(run_mod.Progress):
        def update(self, force: bool = False) -> None:
            if self.cell.clock.now() >= 40.0 and not getattr(self, "sent", False):
                self.sent = True
                signal.raise_signal(signal.SIGINT)

    monkeypatch.setattr(run_mod, "Progress", CtrlC)
    db = tmp_path / "stop.db"
    report = run(db, duration=600.0)
    assert report["interrupted"] and report["state"] == "STOPPED"
    assert report["feed_seconds"] < 45.0
    total = sum(report["parts"]["retrieved"].values())
    assert total > 0
    assert rows(db, "SELECT count(*) FROM events WHERE kind='retrieved'") == [(total,)]
    assert rows(db, "SELECT count(*) > 0 FROM samples") == [(1,)]
    assert json.loads(rows(db, "SELECT report FROM runs")[0][0])["interrupted"] is True


def test_hard_interrupt_keeps_events_and_report_shows_incomplete(tmp_path, monkeypatch,
                                                                 capsys):
    """A second Ctrl-C escapes run_job: no report, but what was buffered is in the log."""
    monkeypatch.setattr(EventLog, "periodic_flush", lambda self: None)

    class SecondCtrlC(run_mod.Progress):
        def update(self, force: bool = False) -> None:
            if force:
                raise KeyboardInterrupt

    monkeypatch.setattr(run_mod, "Progress", SecondCtrlC)
    db = tmp_path / "hard.db"
    with pytest.raises(KeyboardInterrupt):
        run(db, duration=60.0)
    assert rows(db, "SELECT report FROM runs") == [(None,)]
    n = rows(db, "SELECT count(*) FROM events WHERE kind='retrieved'")[0][0]
    assert n > 0
    assert cli_main(["report", str(db), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["state"] == "incomplete"
    assert summary["retrieved"] == {"lens": n} and summary["missed"] is None


def test_runs_accumulate_and_last_selects_the_newest(tmp_path, capsys):
    db = tmp_path / "two.db"
    run(db, duration=30.0, seed=1)
    run(db, duration=30.0, seed=2)
    assert cli_main(["report", str(db)]) == 0
    lines = capsys.readouterr().out.splitlines()
    # header + two runs (a run with faults or misses adds a "run N: ..." line of them)
    assert len([s for s in lines if not re.match(r"run \d+: ", s)]) == 3
    assert cli_main(["report", str(db), "--last", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["seed"] == 2
    assert rows(db, "SELECT DISTINCT run_id FROM events ORDER BY 1") == [(1,), (2,)]


class _Colour(enum.Enum):
    RED = "red"


class _FakeCell:
    def __init__(self) -> None:
        self.stats = Stats()
        self.listeners: list = []


def test_log_batches_rebinds_and_serialises_odd_values(tmp_path):
    cell = _FakeCell()
    log = EventLog(tmp_path / "unit.db", flush_every=3, flush_wall_s=1e9)
    run_id = log.start_run({"scenario": "s", "cell": "c", "seed": 7, "hal": "sim", "x": 1})
    log.attach(cell)
    cell.stats.emit(1.0, "odd", a=np.float32(1.5), b=np.int64(2), c=_Colour.RED,
                    d=ValueError("boom"))
    log.periodic_flush()
    assert rows(tmp_path / "unit.db", "SELECT count(*) FROM events") == [(0,)]   # buffered
    old = cell.stats
    cell.stats = Stats()                    # what Cell.start() does
    cell.stats.emit(2.0, "state", new="STARTING")
    for fn in cell.listeners:
        fn(None, None)
    old.emit(3.0, "stale")                  # the old Stats is no longer followed
    cell.stats.timeline.append({"t": 2.5, "queue": 4, "horizontal_mm_s": 150.0,
                                "incline_pct": 40.0, "robot_speed_pct": 100.0,
                                "retrieved": 0, "target": 9})
    cell.stats.emit(3.0, "retrieved", type="lens")
    log.periodic_flush()                    # third event: batch is due
    got = rows(tmp_path / "unit.db", "SELECT t, kind, data FROM events ORDER BY rowid")
    assert [(t, k) for t, k, _ in got] == [(1.0, "odd"), (2.0, "state"), (3.0, "retrieved")]
    assert json.loads(got[0][2]) == {"a": 1.5, "b": 2, "c": "red", "d": "boom"}
    assert rows(tmp_path / "unit.db", "SELECT run_id, t, queue, extra FROM samples") == [
        (run_id, 2.5, 4, '{"target":9}')]
    log.finish({"ok": True})
    log.close()
    log.close()                             # twice is harmless
    assert json.loads(rows(tmp_path / "unit.db", "SELECT options FROM runs")[0][0]) == {"x": 1}


def test_rolling_ppm():
    t = np.arange(0.5, 300.5, 0.5)
    cumulative = np.floor(t)                # one part a second
    ppm = rolling_ppm(t, cumulative, window_s=60.0, t0=0.0)
    assert np.isnan(ppm[t < 10.0]).all()
    assert np.allclose(ppm[t >= 60.0], 60.0, atol=1.5)
    assert rolling_ppm(np.zeros(0), np.zeros(0)).size == 0


def test_a_killed_runs_summary_counts_the_recoveries_its_log_holds(tmp_path):
    """A run whose final report never reached the log (killed) is summarised from its
    events: every recovery the cell made, the e-stop's and the conveyor's included, is an
    event, so the summary counts as many as the run's own report did."""
    from feeder_bt.app.run import RunOptions, run_job
    from feeder_bt.core.vocabulary import story
    from feeder_bt.records.runs_db import summary

    plan = tmp_path / "plan.yaml"
    plan.write_text("seed: 1\nrates:\n  servo_timeout: {per_pick: 0.02}\nscripted:\n"
                    "  - {at_s: 60, kind: estop, release_after_s: 10}\n"
                    "  - {at_s: 200, kind: comms_lost, device: galil, outage_s: 4}\n")
    db = tmp_path / "runs.db"
    report = run_job(RunOptions(scenario=LENSES, duration=400.0, fast=True, seed=3,
                                view="none", db=str(db), faults=str(plan)))
    counted = re.compile(r"faults (\d+).*recovered (\d+)")
    whole = counted.search(story(report)[0]).groups()
    assert int(whole[1]) >= 3 and report["recoveries"].get("estop"), story(report)
    with sqlite3.connect(db) as conn:
        conn.execute("UPDATE runs SET report=NULL")        # as if killed before the end
    with sqlite3.connect(db) as conn:
        conn.row_factory = sqlite3.Row
        rebuilt = summary(conn, 1)
    assert rebuilt["state"] == "incomplete"
    assert counted.search(rebuilt["story"][0]).groups() == whole, rebuilt["story"]
