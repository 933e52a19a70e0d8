"""One meaning per word: a *fault* stops or degrades the cell, a *miss* is a grab or
pick the trees retry, an *alarm* is a fault that stopped the cell until the reset. The words
are defined once (docs/faults.md, as feeder_bt/core/vocabulary.py says), and no doc, CLI or UI
string uses one in another's meaning; the report, its plot and replay keep them apart."""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path

import pytest

from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.cli.replay_cmd import faults as replay_faults
from feeder_bt.core import vocabulary
from feeder_bt.records.runs_db import series

ROOT = Path(__file__).resolve().parents[2]
LENSES = str(ROOT / "scenarios/lenses.yaml")
WORDS = ("fault", "miss", "alarm")


def texts() -> dict[Path, str]:
    """Docs, the CLI and UI sources: everything a user reads."""
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
             *sorted((ROOT / "feeder_bt").rglob("*.py")),
             *sorted((ROOT / "feeder_bt/ui/static").glob("*.*"))]
    return {p: p.read_text(errors="replace") for p in paths if p.suffix in (".md", ".py", ".js",
                                                                          ".html")}


def _definition(text: str, word: str) -> str:
    m = re.search(rf"an? \*\*{word}\*\* ([^;]*?)[;.]\n", text.replace("\n  ", " "))
    return " ".join(m.group(1).split()) if m else ""


def test_each_word_is_defined_once_and_as_the_code_says():
    found = {w: [p for p, t in texts().items() if re.search(rf"an? \*\*{w}\*\* ", t)]
             for w in WORDS}
    docs = ROOT / "docs/faults.md"
    vocab = ROOT / "feeder_bt/core/vocabulary.py"
    for w in WORDS:
        assert sorted(found[w]) == sorted([docs, vocab]), (w, found[w])
        d = _definition(docs.read_text(), w)
        assert d and d == _definition(vocab.read_text(), w), w


# a miss called a fault, or a fault called a miss: each pattern is one way to say it
MIXED = [
    r"missed[ _]grabs?\s+(?:is|are|counts? as|counted as)\s+(?:an?\s+)?(?:fault|alarm)",
    r"missed[ _]grab\s+faults?\b",
    r"(?:fault|alarm)s?\s*\((?:missed_grab|envelope)\)",
    r"\"fault\"[^\n]{0,60}(?:missed_grab|envelope)",
    r"(?:servo[ _]time-?outs?|link drops?|e-stops?)\s+(?:is|are)\s+(?:an?\s+)?miss(?:es)?\b",
]


@pytest.mark.parametrize("pattern", MIXED)
def test_no_text_mixes_the_words(pattern):
    bad = [f"{p.relative_to(ROOT)}: {m.group(0)!r}" for p, t in texts().items()
           if p.name not in ("test_vocabulary.py",)
           for m in re.finditer(pattern, t, flags=re.I)]
    assert not bad, bad


def test_the_miss_kinds_are_what_the_trees_retry():
    faults, misses = vocabulary.split({"missed_grab": 3, "envelope": 1, "servo_timeout": 2,
                                       "comms_lost": 0})
    assert faults == {"servo_timeout": 2} and misses == {"missed_grab": 3, "envelope": 1}


# the shift plan's faults, ten times as often, and its e-stop early: twenty minutes tell
# what its first two hours do
SHORT_SHIFT = """\
seed: 1
rates:
  servo_timeout: {per_pick: 0.02}
  comms_lost: {per_hour: 12, device: alternate, outage_s: 2.0}
  grab_failed: {per_frame: 0.01}
scripted:
  - {at_s: 600, kind: estop, release_after_s: 60}
"""


@pytest.fixture(scope="module")
def shift_run(tmp_path_factory):
    """Twenty minutes of a denser shift plan, with one e-stop."""
    tmp = tmp_path_factory.mktemp("vocab")
    db, plan = tmp / "r.db", tmp / "plan.yaml"
    plan.write_text(SHORT_SHIFT)
    report = run_job(RunOptions(scenario=LENSES, duration=1200.0, fast=True, seed=1,
                                view="none", db=str(db), faults=str(plan)))
    return report, db


def test_a_fault_run_summary_tells_faults_misses_and_alarms(shift_run):
    report, _ = shift_run
    assert "missed_grab" not in report["faults"] and report["misses"]["missed_grab"] > 0
    text = summary(report)
    n_faults = sum(report["faults"].values())
    assert n_faults > 0
    assert f"faults {n_faults} (injected {sum(report['injected'].values())})" in text
    assert f"recovered {sum(min(v, report['faults'][k]) for k, v in report['recoveries'].items())}" \
        in text
    assert f"misses {sum(report['misses'].values())} (" in text and "missed grab" in text
    assert "alarms 1 (e-stop 1)" in text                       # the scripted e-stop
    assert "ceiling" in text and "bound" in text               # what limited the run
    assert all(len(line) <= 80 for line in text.splitlines()), text


def test_report_plot_and_replay_keep_misses_apart(shift_run, capsys):
    report, db = shift_run
    conn = sqlite3.connect(db)
    s = series(conn, 1)
    assert s.faults_t.size == sum(report["faults"].values())
    assert s.misses_t.size == sum(report["misses"].values())
    found, misses = replay_faults(conn, 1)
    assert len(found) == s.faults_t.size and misses == s.misses_t.size
    conn.close()
    assert main(["report", str(db)]) == 0
    out = capsys.readouterr().out
    assert f"run 1: faults {sum(report['faults'].values())} " in out and "misses " in out


def test_a_run_with_only_misses_had_no_fault_and_says_so(tmp_path, capsys):
    db = tmp_path / "quiet.db"
    r = run_job(RunOptions(scenario=LENSES, duration=60.0, fast=True, seed=1, view="none",
                           db=str(db)))
    assert main(["replay", str(db), "--before-fault"]) == 2
    err = capsys.readouterr().err
    n = sum(r["misses"].values())
    assert "had no fault" in err and (n == 0 or f"({n} miss" in err), err


def test_the_story_names_the_links_that_reconnected():
    report = {"faults": {"comms_lost": 2}, "recoveries": {"comms_lost": 2},
              "watchdog_stops": 1, "reconnects": {"galil": 2, "adept": 0}}
    line = vocabulary.story(report)[0]
    assert "watchdog stopped the belts 1 times" in line
    assert line.endswith("links reconnected: galil 2") and "adept" not in line
