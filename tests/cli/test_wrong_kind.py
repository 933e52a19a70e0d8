"""A file of the wrong kind, given to any command, is one line naming what it looks like and
what was expected, exit 2: never a line for each key the expected kind does not have
(`feeder render cells/sim.yaml` printed ten lines of `unknown key`/`missing required key`,
`--world scenarios/squares.yaml` nine of `not a world figure`). The loaders themselves
say it, so every command that loads a file does."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
RUN = ["--fast", "--duration", "1", "--no-db", "--view", "none"]


@pytest.fixture(autouse=True)
def _at_the_root(monkeypatch):
    monkeypatch.chdir(ROOT)


@pytest.mark.parametrize("argv,what", [
    (["render", "cells/sim.yaml", "--frames", "1"],
     "cells/sim.yaml: this is a cell description, not a scenario: give it with --cell"),
    (["render", "supply/batch_refill.yaml", "--frames", "1"],
     "supply/batch_refill.yaml: this is a supply plan, not a scenario: give it with --supply"),
    (["tree", "faults/shift.yaml", "--format", "ascii"],
     "faults/shift.yaml: this is a fault plan, not a scenario: give it with --faults"),
    (["tree", "examples/plant_b.yaml", "--format", "ascii"],
     "examples/plant_b.yaml: this is a world file, not a scenario: give it with --world"),
    (["run", "scenarios/lenses.yaml", "--world", "scenarios/squares.yaml", *RUN],
     "scenarios/squares.yaml: this is a scenario, not a world file"),
    (["run", "scenarios/lenses.yaml", "--world", "supply/batch_refill.yaml", *RUN],
     "supply/batch_refill.yaml: this is a supply plan, not a world file"),
    (["run", "scenarios/lenses.yaml", "--cell", "examples/plant_b.yaml", *RUN],
     "examples/plant_b.yaml: this is a world file, not a cell description (--cell)"),
    (["calibrate", "camera", "scenarios/lenses.yaml"],
     "scenarios/lenses.yaml: this is a scenario, not a cell description"),
])
def test_a_file_of_the_wrong_kind_is_one_line(argv, what, tmp_path, capsys):
    if argv[0] == "render":
        argv = [*argv, "--out", str(tmp_path / "frames")]
    with pytest.raises(SystemExit) as e:
        code = main(argv)
        raise SystemExit(code)
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and what in err[0], err
    assert not (tmp_path / "frames").exists() or not any((tmp_path / "frames").iterdir())


def test_a_scenario_whose_cell_key_names_a_scenario(tmp_path, capsys):
    (tmp_path / "cells").mkdir()
    text = (ROOT / "scenarios/lenses.yaml").read_text()
    (tmp_path / "cells" / "sim.yaml").write_text(text)          # a scenario where a cell goes
    (tmp_path / "scenarios").mkdir()
    (tmp_path / "scenarios" / "lenses.yaml").write_text(text)
    with pytest.raises(SystemExit) as e:
        raise SystemExit(main(["tree", str(tmp_path / "scenarios/lenses.yaml")]))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "this is a scenario, not a cell description" in err[0], err


def test_a_world_file_with_a_misspelt_section_is_still_a_world_file(tmp_path, capsys):
    # its other sections are a cell's too: the misspelt key is named, not "a cell description"
    world = tmp_path / "plant.yaml"
    world.write_text("camra:\n  fps: 10\nconveyors:\n  horizontal: {max_mm_s: 300}\n")
    code = main(["run", "scenarios/lenses.yaml", "--world", str(world), *RUN])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "camra: not a world figure (did you mean 'camera'?)" in err[0], err
