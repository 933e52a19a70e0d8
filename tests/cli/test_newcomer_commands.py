"""A newcomer's first commands: a missing file names the nearest one, Ctrl-C while
the first imports run ends in one line, the tree glyphs have a legend, and the README's tour
writes only into the ignored ``out/``."""

from __future__ import annotations

import importlib
import re
import shlex
from pathlib import Path

import pytest

from feeder_bt.app.view import LEGEND
from feeder_bt.cli import main as cli
from feeder_bt.core.didyoumean import hint, nearest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("typed,want", [
    ("scenarios/lense.yaml", "scenarios/lenses.yaml"),
    ("cells/sim.yml", "cells/sim.yaml"),
    ("scenario/lenses.yaml", "scenarios/lenses.yaml"),      # the folder mistyped
    ("faults/shfit.yaml", "faults/shift.yaml"),
])
def test_a_missing_file_names_the_nearest(typed, want, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    assert nearest(typed) == want
    assert cli.main(["check", typed]) != 0
    err = capsys.readouterr()
    assert f"{typed}: file not found (did you mean {want}?)" in err.out + err.err


def test_nothing_close_suggests_nothing(monkeypatch):
    monkeypatch.chdir(ROOT)
    assert hint("scenarios/zzzzqqqq.yaml") == "" and hint("nowhere/at/all.yaml") == ""


@pytest.mark.parametrize("raise_", [
    KeyboardInterrupt,
    lambda: _wrapped(),                       # numpy's import turns Ctrl-C into ImportError
])
def test_ctrl_c_while_the_tools_are_imported_is_one_line(raise_, monkeypatch, capsys):
    real = importlib.import_module

    def interrupted(name, package=None):
        if name.startswith("feeder_bt.cli."):
            raise raise_()
        return real(name, package)

    monkeypatch.setattr(importlib, "import_module", interrupted)
    assert cli.main(["run", "scenarios/lenses.yaml"]) == 130
    err = capsys.readouterr().err
    assert err == "feeder: interrupted\n"


def _wrapped() -> ImportError:
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt:
        try:
            raise ImportError("numpy: PyCapsule_Import could not import module")
        except ImportError as e:
            return e


def test_an_import_error_of_its_own_is_not_taken_for_ctrl_c(monkeypatch):
    def broken(name, package=None):
        raise ImportError("no module named shapely")

    monkeypatch.setattr(importlib, "import_module", broken)
    with pytest.raises(ImportError):
        cli.main(["run", "scenarios/lenses.yaml"])


def test_the_tree_legend_names_every_glyph_the_trees_use(capsys):
    assert cli.main(["tree", "scenarios/lenses.yaml"]) == 0
    out = capsys.readouterr().out
    used = set(re.findall(r"^\s*(/_/|\{o\}|\[o\]|\{-\}|\[-\]|-\^-|-->) ", out, flags=re.M))
    assert len(used) >= 4
    legend = "\n".join(LEGEND)
    assert all(g in legend for g in used)
    assert out.rstrip().endswith(LEGEND[-1])
    assert cli.main(["tree", "--legend"]) == 0
    assert capsys.readouterr().out.splitlines() == list(LEGEND)


def test_the_tour_writes_only_into_out_and_out_is_ignored():
    readme = (ROOT / "README.md").read_text()
    tour = re.search(r"## A short tour\n\n```sh\n(.*?)```", readme, flags=re.S).group(1)
    written = []
    for line in tour.splitlines():
        argv = shlex.split(line)
        for flag in ("-o", "--out", "--report", "--annotate", "--plot", "--db"):
            if flag in argv:
                written.append(argv[argv.index(flag) + 1])
    assert len(written) >= 4
    assert all(w.startswith(("out/", "runs/")) for w in written), written
    ignored = (ROOT / ".gitignore").read_text().split()
    assert "/out/" in ignored and "/runs/" in ignored


def test_the_live_view_shows_the_legend_when_there_is_room():
    import io

    from feeder_bt.app.view import STATUS_LEGEND, LiveView
    from tests.app.test_view import _cell
    cell, ticker = _cell()
    cell.start()
    ticker.run(until=30.0)
    view = LiveView(cell, out=io.StringIO())
    tall = view.lines(200, 400)
    assert any(s.startswith(LEGEND[0]) and STATUS_LEGEND in s for s in tall)
    short = view.lines(80, 12)                  # no room: the trees keep every row
    assert not any(LEGEND[0] in s for s in short)


@pytest.mark.parametrize("argv", [["calibrate", "camera"], ["calibrate", "belt"],
                                  ["commission", "galil"], ["commission", "adept"]])
def test_a_scenario_where_a_cell_belongs_is_one_line(argv, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    assert cli.main([*argv, "scenarios/lenses.yaml"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["feeder: scenarios/lenses.yaml: this is a scenario, not a cell description: "
                   "give the cell description it runs on (its `cell:` key names it)"]


def test_a_render_into_a_used_folder_replaces_the_earlier_render_only(tmp_path, capsys,
                                                                        monkeypatch):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "frames"
    assert cli.main(["render", "scenarios/squares.yaml", "--out", str(out), "--frames", "3",
                     "--truth"]) == 0
    (out / "notes.txt").write_text("mine\n")
    capsys.readouterr()
    assert cli.main(["render", "scenarios/lenses.yaml", "--out", str(out), "--frames", "1"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frame_000.png", "golden.png", "notes.txt"]
    assert "removed 7 file(s) of an earlier render" in capsys.readouterr().out
