"""A run's result is never lost to a bad --report path: one the run could never write is
refused before the run starts (exit 2, one line); one that fails at the end (a folder
removed, a disk full) sends the report to a fallback file named in one line, and the run's
row in the event log is finished first."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.core.outputs import write_or_fallback

ROOT = Path(__file__).resolve().parents[2]
SCENARIO = str(ROOT / "scenarios" / "lenses.yaml")


@pytest.mark.parametrize("bad", ["dir", "/proc/version", "afile/x.json"])
def test_a_report_path_that_cannot_be_written_is_refused_before_the_run(bad, tmp_path,
                                                                         capsys):
    (tmp_path / "afile").write_text("a file, not a folder\n")
    (tmp_path / "dir").mkdir()
    path = bad if bad.startswith("/") else str(tmp_path / bad)
    db = tmp_path / "runs.db"
    code = main(["run", SCENARIO, "--duration", "5", "--fast", "--view", "none", "--db",
                 str(db), "--report", path])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert err.count("\n") == 0 and "Traceback" not in err and "--report" in err, err
    assert not db.exists()                     # refused before anything opened


def test_a_report_that_fails_at_the_end_goes_to_a_fallback_file(tmp_path, monkeypatch,
                                                                  capsys):
    monkeypatch.chdir(tmp_path)
    # the path was fine when the run started; by its end the folder has become a file
    monkeypatch.setattr("feeder_bt.app.run.check_output_file", lambda *a: None)
    (tmp_path / "gone").write_text("")
    db = tmp_path / "runs.db"
    report = run_job(RunOptions(scenario=SCENARIO, duration=20.0, fast=True, seed=1,
                                view="none", db=str(db), report=str(tmp_path / "gone" / "r.json")))
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "cannot write the run report" in x)
    dest = Path(line.rsplit("written to ", 1)[1].split(" instead")[0])
    assert dest.resolve().parent == tmp_path / "runs"
    assert json.loads(dest.read_text())["parts"] == report["parts"]
    with sqlite3.connect(db) as conn:
        (ended,) = conn.execute("SELECT ended FROM runs").fetchone()
    assert ended                                # the row was finished all the same


def test_the_fallback_names_where_it_wrote(tmp_path, capsys):
    (tmp_path / "f").write_text("")
    dest = write_or_fallback(tmp_path / "f" / "r.json", "{}\n", "run report", tmp_path / "fb")
    assert dest.parent == tmp_path / "fb" and dest.read_text() == "{}\n"
    assert str(dest) in capsys.readouterr().err
