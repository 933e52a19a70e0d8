"""Every outcome the world sees, the cell sees: a placement the cell did not count, and a
count the world never saw placed, are each a counted mismatch, named in the summary and
the end of the run (exit 4). Each test breaks the cell's count on purpose."""

from __future__ import annotations

from pathlib import Path

import pytest

import feeder_bt.behaviours.retrieve as retrieve
from feeder_bt.analysis.report import outcome_mismatch
from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import EXIT_ACCOUNTING, main

ROOT = Path(__file__).resolve().parents[2]
LENSES = str(ROOT / "scenarios" / "lenses.yaml")


def _break(monkeypatch, every: int, times: int) -> None:
    """The cell counts the ``every``-th placement ``times`` times (0: not at all)."""
    real = retrieve.count_retrieved
    seen = {"n": 0}

    def counted(ctx, part, **data):
        seen["n"] += 1
        for _ in range(1 if seen["n"] % every else times):
            real(ctx, part, **data)
    monkeypatch.setattr(retrieve, "count_retrieved", counted)


@pytest.mark.parametrize("times,side", [(0, "world_only"), (2, "cell_only")])
def test_a_placement_the_two_do_not_agree_on_is_a_named_mismatch(monkeypatch, times, side):
    _break(monkeypatch, every=10, times=times)
    report = run_job(RunOptions(scenario=LENSES, duration=120.0, fast=True, seed=1,
                                view="none"))
    placed = sum(report["parts"]["retrieved"].values())
    n = report["parts"]["outcomes"][side]["lens"]
    assert n >= 1 and n == (placed + n) // 10 if side == "world_only" else n >= 1
    text = summary(report)
    assert "MISMATCH" in text and ("did not count" if times == 0 else "never saw") in text


def test_a_mismatch_ends_the_run_with_the_accounting_exit(monkeypatch, capsys):
    _break(monkeypatch, every=10, times=0)
    code = main(["run", LENSES, "--fast", "--duration", "60", "--view", "none", "--no-db"])
    assert code == EXIT_ACCOUNTING
    assert "placements the world and the cell do not agree on" in capsys.readouterr().err


def test_an_honest_run_has_no_mismatch():
    report = run_job(RunOptions(scenario=LENSES, duration=120.0, fast=True, seed=1,
                                view="none"))
    assert "outcomes" not in report["parts"]
    assert outcome_mismatch({"lens": 3}, {"lens": 3}) == {}
    assert outcome_mismatch({"lens": 3}, {"lens": 2, "square": 1}) == {
        "world_only": {"lens": 1}, "cell_only": {"square": 1}}
