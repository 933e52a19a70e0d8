"""The command line: one-line errors with the right exit codes, reports, tree drawings."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from feeder_bt.cli.main import main

LENSES = Path("scenarios/lenses.yaml").read_text()


def feeder(*args: str) -> subprocess.CompletedProcess:
    """The real entry point in a child process: what a user sees, tracebacks included."""
    if args and args[0] == "run" and "--db" not in args:
        args = (*args, "--no-db")              # keep the repository free of event logs
    return subprocess.run([sys.executable, "-m", "feeder_bt.cli", *args],
                          capture_output=True, text=True, timeout=300)


def bad_scenario(tmp_path: Path, old: str, new: str) -> Path:
    assert old in LENSES
    p = tmp_path / "bad.yaml"
    p.write_text(LENSES.replace(old, new).replace("cell: ../cells/sim.yaml",
                                                  f"cell: {Path('cells/sim.yaml').resolve()}"))
    return p


@pytest.mark.parametrize("old,new,key", [
    ("horizontal_mm_s: 150", "horizontal_mm_s: 5000", "present.horizontal_mm_s"),
    ("horizontal_mm_s: 150", "horizontal_mm_sec: 150", "present.horizontal_mm_sec"),
    ("policy: fifo", "policy: random", "retrieve.policy"),
    ("{probability: 0.85, pickable: true}", "{probability: 0.95, pickable: true}",
     "parts.lens.poses"),
    ("frame_spacing_mm: 300", "frame_spacing_mm: [300", None),
])
def test_bad_scenario_is_one_line_and_exit_2(tmp_path, old, new, key):
    path = bad_scenario(tmp_path, old, new)
    res = feeder("run", str(path), "--fast", "--duration", "5")
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1, res.stderr
    assert "Traceback" not in res.stderr
    assert str(path) in lines[0]
    if key:
        assert f": {key}:" in lines[0]


def test_missing_file_and_bad_arguments(tmp_path):
    res = feeder("run", str(tmp_path / "nope.yaml"))
    assert res.returncode == 2 and "nope.yaml" in res.stderr and "Traceback" not in res.stderr
    res = feeder("run", "scenarios/lenses.yaml", "--duration", "-1")
    assert res.returncode == 2 and len(res.stderr.strip().splitlines()) == 1
    res = feeder("run", "scenarios/lenses.yaml", "--hal", "real")
    assert res.returncode == 2 and "Traceback" not in res.stderr


def test_check_reports_every_bad_file(tmp_path, capsys):
    good = "scenarios/lenses.yaml"
    bad = bad_scenario(tmp_path, "tick_hz: 200", "tick_hz: 2")
    assert main(["check", good, str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tick_hz" in err[0]
    assert main(["check", good, "scenarios/squares.yaml", "cells/sim.yaml"]) == 0


def test_run_writes_the_report(tmp_path, capsys):
    out = tmp_path / "r.json"
    rc = main(["run", "scenarios/lenses.yaml", "--fast", "--duration", "60", "--seed", "5",
               "--report", str(out), "--no-db"])
    assert rc == 0
    rep = json.loads(out.read_text())
    for key in ("scenario", "seed", "hal", "sim_seconds", "wall_seconds", "parts_per_minute",
                "faults", "recoveries"):
        assert key in rep
    for key in ("retrieved", "located", "missed", "recirculated", "misoriented", "lost"):
        assert key in rep["parts"]
    for key in ("hz", "p50_ms", "p99_ms", "max_ms", "overruns"):
        assert key in rep["tick"]
    for key in ("frames", "p50_ms", "p99_ms"):
        assert key in rep["vision"]
    assert rep["seed"] == 5 and rep["hal"] == "sim" and rep["parts"]["lost"] == 0
    assert "retrieved" in capsys.readouterr().out


@pytest.mark.parametrize("fmt,needle", [("ascii", "retrieve"), ("unicode", "retrieve"),
                                         ("dot", "digraph")])
def test_tree_formats(fmt, needle, capsys):
    assert main(["tree", "scenarios/lenses.yaml", "--format", fmt]) == 0
    out = capsys.readouterr().out
    assert needle in out
    for branch in ("present", "locate", "retrieve", "adjust"):
        assert branch in out


@pytest.mark.skipif(shutil.which("dot") is None, reason="Graphviz not installed")
def test_tree_svg(tmp_path):
    out = tmp_path / "t.svg"
    assert main(["tree", "scenarios/squares.yaml", "--format", "svg", "-o", str(out)]) == 0
    assert out.read_text().lstrip().startswith(("<?xml", "<svg"))


def test_sigint_stops_in_order_and_still_reports(tmp_path):
    out = tmp_path / "r.json"
    proc = subprocess.Popen([sys.executable, "-m", "feeder_bt.cli", "run",
                             "scenarios/lenses.yaml", "--view", "ascii", "--duration", "600",
                             "--report", str(out), "--db", str(tmp_path / "r.db")],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # wait for the first status line: the cell is running in real time
        line = proc.stdout.readline()
        assert "STARTING" in line or "RUNNING" in line, line
        proc.send_signal(2)
        stdout, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 0, stderr
    rep = json.loads(out.read_text())
    assert rep["interrupted"] is True and rep["state"] == "STOPPED"
    assert "STOPPED (interrupted)" in stdout
    assert rep["parts"]["lost"] == 0


# ---------------------------------------------------------------------------- polish


@pytest.mark.parametrize("argv,hint", [
    (["run", "scenarios/lenses.yaml", "--fsat"], "did you mean --fast?"),
    (["run", "scenarios/lenses.yaml", "--duraton=5"], "did you mean --duration?"),
    (["rnu", "scenarios/lenses.yaml"], "did you mean run?"),
    (["tree", "scenarios/lenses.yaml", "--format", "asci"], "did you mean ascii?"),
    (["check", "--imgaes"], None),
])
def test_a_misspelt_option_gets_a_did_you_mean(argv, hint, capsys):
    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    if hint:
        assert hint in err[0]


@pytest.mark.parametrize("argv,needle", [
    (["run", "scenarios/lenses.yaml", "--ui", "127.0.0.1:0", "--fast"], "drop --fast"),
    (["run", "scenarios/lenses.yaml", "--hal", "emulated", "--fast"], "--fast needs"),
])
def test_options_that_do_not_go_together_exit_2(argv, needle, capsys):
    assert main([*argv, "--no-db"]) == 2         # docs/getting-started.md: usage mistakes
    assert needle in capsys.readouterr().err


@pytest.mark.parametrize("argv,what", [
    (["run", "cells/sim.yaml"], "cells/sim.yaml: this is a cell description, not a scenario"),
    (["run", "faults/shift.yaml"], "faults/shift.yaml: this is a fault plan, not a scenario"),
    (["run", "scenarios/lenses.yaml", "--cell", "scenarios/squares.yaml"],
     "this is a scenario, not a cell description (--cell)"),
    (["run", "scenarios/lenses.yaml", "--faults", "cells/sim.yaml"],
     "this is a cell description, not a fault plan (--faults)"),
])
def test_a_file_of_the_wrong_kind_is_named_as_what_it_is(argv, what, capsys):
    assert main([*argv, "--no-db"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0], err


def test_check_takes_every_kind_and_says_which(tmp_path, capsys):
    files = ["scenarios/lenses.yaml", "cells/sim.yaml", "faults/shift.yaml"]
    assert main(["check", *files]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == ["ok: scenarios/lenses.yaml (a scenario)",
                   "ok: cells/sim.yaml (a cell description)",
                   "ok: faults/shift.yaml (a fault plan)"]
    bad = tmp_path / "plan.yaml"
    bad.write_text(Path("faults/shift.yaml").read_text().replace("per_pick", "per_pik"))
    assert main(["check", str(bad), "cells/sim.yaml"]) == 2
    captured = capsys.readouterr()
    first, *more = captured.err.strip().splitlines()
    assert "per_pik" in first and first.endswith("(read as a fault plan)")
    line = next(i for i, s in enumerate(bad.read_text().splitlines(), 1)
                if "servo_timeout: {per_pik" in s)
    assert first.startswith(f"{bad}:{line}: rates.servo_timeout.per_pik: unknown key "
                            "'per_pik' (did you mean 'per_pick'?)")
    assert more == []           # the missing per_pick is that same mistake, not a second
    assert captured.out.splitlines() == ["ok: cells/sim.yaml (a cell description)",
                                         "1 problem in 1 of 2 files"]


def test_the_dot_graph_is_named_after_the_scenario(capsys):
    assert main(["tree", "scenarios/lenses.yaml", "--format", "dot"]) == 0
    assert capsys.readouterr().out.startswith("digraph lenses_feeding {")
    assert main(["tree", "scenarios/squares.yaml", "--format", "dot", "--part", "setup"]) == 0
    assert capsys.readouterr().out.startswith("digraph squares_setup {")


def test_the_summary_fits_80_columns_and_says_interrupted():
    from feeder_bt.analysis.summary import summary
    report = {"scenario": "lenses_and_squares", "state": "STOPPED", "interrupted": True,
              "feed_seconds": 3600.0, "wall_seconds": 3600.4, "parts_per_minute": 104.567,
              "parts": {"retrieved": {"lens": 3000, "square": 3274}, "located": 7000,
                        "missed": 12, "lost": 0}}
    lines = summary(report).splitlines()
    assert "STOPPED (interrupted) after 3600 s" in lines[0]
    assert lines[1] == "  104.6 parts/min, retrieved 6274 (lens 3000, square 3274)"
    assert all(len(s) <= 80 for s in lines)
