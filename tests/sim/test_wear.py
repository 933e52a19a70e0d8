"""Wear: a part type may travel the belt at most ``max_passes`` times; one that
falls off the end on its last pass goes to scrap, counted and never lost, and every report
says how many passes each placed part cost."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.config.loader import load_scenario
from feeder_bt.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]


def lenses(tmp_path: Path, max_passes: object) -> Path:
    text = (ROOT / "scenarios" / "lenses.yaml").read_text()
    text = text.replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    old = "    tool_offset: [0, 0, 0]\n"
    assert old in text
    text = text.replace(old, old + f"    max_passes: {max_passes}\n", 1)
    p = tmp_path / "lenses.yaml"
    p.write_text(text)
    return p


def run(path: Path) -> dict:
    return run_job(RunOptions(scenario=str(path), duration=600.0, fast=True, seed=3,
                              view="none", db=None))


def test_worn_parts_go_to_scrap_and_every_part_is_accounted_for(tmp_path):
    free = run(ROOT / "scenarios" / "lenses.yaml")
    worn = run(lenses(tmp_path, 2))
    assert free["parts"]["scrapped"] == 0 and free["parts"]["recirculated"] > 100
    p = worn["parts"]
    # a lens may fall off the end once (its first pass) and goes to scrap the second time
    assert p["scrapped"] > 20 and p["recirculated"] > p["scrapped"]
    assert p["lost"] == 0 and p["duplicated"] == 0
    census = worn["world"]["census"]
    assert census["scrapped"] == p["scrapped"] and sum(census.values()) == p["supplied"]
    # every recirculated lens had a pass left; none recirculated twice
    assert p["recirculated"] <= p["supplied"]
    assert worn["parts"]["recirculated_per_placed"] == pytest.approx(
        p["recirculated"] / sum(p["retrieved"].values()), abs=1e-3)
    assert "scrapped" in summary(worn) and "scrapped" not in summary(free)
    assert "per placed" in summary(free)


def test_one_pass_only_recirculates_nothing(tmp_path):
    p = run(lenses(tmp_path, 1))["parts"]
    assert p["recirculated"] == 0 and p["scrapped"] > 50 and p["lost"] == 0


def test_max_passes_must_be_a_count(tmp_path, capsys):
    with pytest.raises(ConfigError) as e:
        load_scenario(lenses(tmp_path, -1))
    assert "max_passes" in str(e.value) and "\n" not in str(e.value)
    assert main(["check", str(lenses(tmp_path, "often"))]) == 2
    err = capsys.readouterr().err
    assert "max_passes" in err and "Traceback" not in err


def test_feeder_report_gives_the_scrapped_parts(tmp_path, capsys):
    import json
    db = tmp_path / "e.db"
    r = run_job(RunOptions(scenario=str(lenses(tmp_path, 1)), duration=300.0, fast=True,
                           seed=3, view="none", db=str(db)))
    assert r["parts"]["scrapped"] > 10
    capsys.readouterr()
    assert main(["report", str(db), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)             # one run: its summary
    assert row["scrapped"] == r["parts"]["scrapped"]
    assert main(["report", str(db)]) == 0
    table = capsys.readouterr().out.splitlines()
    assert "scrapped" in table[0].split()
