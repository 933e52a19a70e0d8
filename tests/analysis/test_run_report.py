"""The run report's types and schema (``feeder schema report``): every report the tests
write is checked against the schema (tests/conftest.py sets FEEDER_CHECK_REPORTS), a report
read back is the same JSON written again, and a broken report fails the check."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import jsonschema
import pytest

from feeder_bt.analysis.run_report import ABSENT, ReportError, RunReport, report_schema
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def report() -> dict:
    return run_job(RunOptions(scenario=str(ROOT / "scenarios" / "lenses.yaml"), duration=60,
                              fast=True, seed=1, view="none"))


def test_a_report_read_back_is_the_same_json_in_the_same_order(report):
    back = RunReport.from_json(copy.deepcopy(report))
    assert json.dumps(back.to_json()) == json.dumps(report)
    assert back.parts.retrieved == report["parts"]["retrieved"]
    assert back.kits is ABSENT and "kits" not in back.to_json()


def test_the_schema_holds_a_report_and_refuses_a_broken_one(report):
    schema = report_schema()
    jsonschema.validate(report, schema)
    for broken in (lambda r: r.pop("parts_per_minute"),
                   lambda r: r.__setitem__("parts_per_minute", "64.4"),
                   lambda r: r["parts"].__setitem__("lost", "none"),
                   lambda r: r.__setitem__("partz", {})):
        r = copy.deepcopy(report)
        broken(r)
        with pytest.raises(jsonschema.ValidationError):
            jsonschema.validate(r, schema)


def test_a_key_missing_or_unknown_is_named_when_read_back(report):
    r = copy.deepcopy(report)
    r.pop("parts_per_minute")
    with pytest.raises(ReportError, match="parts_per_minute: missing"):
        RunReport.from_json(r)
    r = copy.deepcopy(report)
    r["parts"]["partz"] = 1
    with pytest.raises(ReportError, match="parts.partz: not a key of the report"):
        RunReport.from_json(r)


def test_feeder_schema_report_prints_the_schema(capsys):
    assert main(["schema", "report"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed == json.loads(json.dumps(report_schema()))
    assert "parts_per_minute" in printed["required"] and "kits" not in printed["required"]


def test_a_written_report_is_checked_before_it_is_written(tmp_path, monkeypatch):
    from feeder_bt.analysis.report import write_report
    monkeypatch.setenv("FEEDER_CHECK_REPORTS", "1")
    with pytest.raises(jsonschema.ValidationError):
        write_report({"scenario": "x"}, tmp_path / "r.json")
    assert not (tmp_path / "r.json").exists()
