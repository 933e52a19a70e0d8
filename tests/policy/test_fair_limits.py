"""Fair limits: every adjuster and every fixed setting runs under the cell's
conveyor limits. An adjuster parameter that could drive a belt faster is refused at load,
like a fixed speed; the simulated belt refuses a speed above its ``max_mm_s`` instead of
clamping it."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.config import load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import ConfigError, HalError
from feeder_bt.policy.adjusters import ADJUSTERS
from feeder_bt.sim.axis import Axis
from feeder_bt.sim.devices import make_sim_hal

ROOT = Path(__file__).resolve().parents[2]
LENSES = ROOT / "scenarios" / "lenses.yaml"
CELL = (ROOT / "cells" / "sim.yaml").resolve()


def with_adjust(tmp_path: Path, section: str, present: str | None = None) -> Path:
    """lenses.yaml with its adjust section (and optionally present section) replaced."""
    text = LENSES.read_text().replace("cell: ../cells/sim.yaml", f"cell: {CELL}")
    text = re.sub(r"^adjust:\n(?:[ #].*\n|\n)*", section, text + "\n", flags=re.M)
    if present is not None:
        text = re.sub(r"^present:\n(?:[ #].*\n|\n)*", present, text, flags=re.M)
    out = tmp_path / "s.yaml"
    out.write_text(text)
    return out


def line_of(path: Path, needle: str) -> int:
    return next(i for i, line in enumerate(path.read_text().splitlines(), 1) if needle in line)


def refused(path: Path) -> ConfigError:
    with pytest.raises(ConfigError) as e:
        load_scenario(path)
    msg = str(e.value)
    assert "\n" not in msg
    return e.value


def test_a_percentage_parameter_beyond_the_incline_limit_is_refused(tmp_path):
    p = with_adjust(tmp_path, "adjust:\n  algorithm: supply_queue\n  params:\n"
                              "    horizontal_mm_s: 250\n    max_mm_s: 400\n"
                              "    max_incline_pct: 200\n")
    e = refused(p)
    assert e.line == line_of(p, "max_incline_pct: 200")
    assert e.key == "adjust.params.max_incline_pct"
    assert str(e).startswith(f"{p}:{e.line}: adjust.params.max_incline_pct: ")
    # names the speed, the limit and where the limit comes from
    assert "800 mm/s" in e.what and "max_mm_s 400" in e.what and str(CELL) in e.what


def test_a_default_that_would_exceed_the_limit_is_named_as_the_default(tmp_path):
    # max_incline_pct defaults to 120: 120 % of 400 mm/s = 480 mm/s on a 400 mm/s incline
    p = with_adjust(tmp_path, "adjust:\n  algorithm: supply_queue\n  params: {max_mm_s: 400}\n")
    e = refused(p)
    assert e.key == "adjust.params.max_incline_pct"
    assert "(the supply_queue default)" in e.what and "480 mm/s" in e.what


def test_the_water_mark_cap_is_checked_like_a_fixed_speed(tmp_path):
    adj = ("adjust:\n  algorithm: water_marks\n  params: {min_mm_s: 80, median_mm_s: 150, "
           "max_mm_s: 500}\n")
    e_adj = refused(with_adjust(tmp_path, adj))
    fixed = "present:\n  mode: continuous\n  horizontal_mm_s: 500\n  incline_pct: 40\n"
    e_fix = refused(with_adjust(tmp_path, "adjust:\n  algorithm: none\n", present=fixed))
    for e in (e_adj, e_fix):       # the same rule, the same message
        assert "above the horizontal conveyor's max_mm_s 400" in e.what
        assert str(CELL) in e.what


def test_a_cap_legal_on_the_belt_but_not_at_the_incline_pct_is_refused(tmp_path):
    # 300 mm/s is fine for the horizontal belt, but the incline runs at 160 % of it
    present = "present:\n  mode: continuous\n  horizontal_mm_s: 150\n  incline_pct: 160\n"
    adj = "adjust:\n  algorithm: water_marks\n  params: {max_mm_s: 300}\n"
    e = refused(with_adjust(tmp_path, adj, present=present))
    assert e.key == "adjust.params.max_mm_s" and "480 mm/s on the incline" in e.what


def test_legal_adjusters_load(tmp_path):
    adj = ("adjust:\n  algorithm: supply_queue\n  params: {horizontal_mm_s: 250, "
           "max_mm_s: 250, max_incline_pct: 160}\n")
    sc, _ = load_scenario(with_adjust(tmp_path, adj))
    assert sc.adjust.params["max_incline_pct"] == 160


def test_every_adjuster_declares_its_envelope():
    for name, cls in ADJUSTERS.items():
        env = cls().envelope(40.0)
        if name == "none":
            assert env == []
            continue
        assert {e.conveyor for e in env} == {"horizontal", "incline"}
        assert all(e.key in cls.PARAMS for e in env)


def test_the_benchmark_configurations_load(tmp_path):
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import throughput_bench as tb
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    for scen in ("lenses", "squares"):
        for adj in tb.ADJUST_SECTIONS:
            load_scenario(tb.variant(ROOT / "scenarios" / f"{scen}.yaml", adj, "lookahead",
                                     tmp_path))


def test_the_simulated_belt_refuses_a_speed_above_its_limit():
    sc, cell = load_scenario(LENSES)
    hal = make_sim_hal(sc, cell, SimClock(), 1)
    try:
        incline = hal.conveyors["incline"]
        job = incline.set_speed(500.0)
        assert job.done and not job.ok
        assert isinstance(job.error, HalError)
        assert "500 mm/s commanded, above its max_mm_s 400" in str(job.error)
        assert incline.speed() == 0.0                 # nothing was commanded
        move = hal.conveyors["horizontal"].move(100.0, 401.0)
        assert move.done and not move.ok
        assert hal.conveyors["horizontal"].set_speed(400.0).error is None
        assert hal.world.incline.clamped == hal.world.horizontal.clamped == 0
    finally:
        hal.close()


def test_an_axis_asked_too_much_saturates_and_counts_it():
    a = Axis(accel_mm_s2=1000.0, max_mm_s=400.0)
    a.jog(0.0, 500.0)
    assert a.commanded == 400.0 and a.clamped == 1
    a.jog(1.0, -400.0)
    assert a.clamped == 1


OVERDRIVE = '''
from feeder_bt.policy.adjusters import Adjuster, Speeds

class Overdrive(Adjuster):
    """A plugin adjuster the loader cannot see into: it asks for 600 mm/s."""
    PARAMS = {}

    def update(self, inp):
        return Speeds(600.0, inp.incline_pct, inp.robot_speed_pct)
'''


def test_a_plugin_adjuster_beyond_the_limit_faults_the_run(tmp_path, monkeypatch):
    (tmp_path / "overdrive_plugin.py").write_text(OVERDRIVE)
    monkeypatch.syspath_prepend(str(tmp_path))
    p = with_adjust(tmp_path, "adjust:\n  period_s: 0.5\n  leaf: overdrive_plugin:Overdrive\n")
    r = run_job(RunOptions(scenario=str(p), duration=30.0, fast=True, view="none"))
    assert r["faults"].get("hal", 0) >= 1           # counted as a conveyor fault, retried
    assert r["state"] == "FAULT" and "600 mm/s commanded, above its max_mm_s 400" in r["fault"]
    assert r["world"]["axis_clamped"] == {"horizontal": 0, "incline": 0}


def test_feeder_check_refuses_it_in_one_line(tmp_path, capsys):
    from feeder_bt.cli.main import main
    p = with_adjust(tmp_path, "adjust:\n  algorithm: supply_queue\n  params: {max_mm_s: 400, "
                              "max_incline_pct: 150}\n")
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "adjust.params.max_incline_pct" in err[0] and "600 mm/s" in err[0]
