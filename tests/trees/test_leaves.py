"""A leaf class a scenario names must be of the kind it replaces (``trees.leaves``): a
wrong one is one line of ``feeder check`` and of ``feeder run``, never a traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario
from feeder_bt.trees.leaves import LEAF_BASES, leaf_problems

ROOT = Path(__file__).resolve().parents[2]
LENSES = (ROOT / "scenarios" / "lenses.yaml").read_text().replace(
    "cell: ../cells/sim.yaml", f"cell: {ROOT / 'cells' / 'sim.yaml'}")


def _with(tmp_path: Path, section: str, spec: str) -> Path:
    lines = LENSES.splitlines()
    at = lines.index(f"{section}:")
    p = tmp_path / "s.yaml"
    p.write_text("\n".join(lines[:at + 1] + [f"  leaf: {spec}"] + lines[at + 1:]) + "\n")
    return p


@pytest.mark.parametrize("section", ["vision", "locate", "retrieve", "adjust"])
def test_a_class_of_another_kind_is_named_by_check_and_by_run(section, tmp_path, capsys):
    p = _with(tmp_path, section, "subprocess:Popen")
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    base = LEAF_BASES[f"{section}.leaf"].__name__
    assert len(err) == 1 and f"{section}.leaf: 'subprocess:Popen' is a class, not a {base}" in err[0]
    assert main(["run", str(p), "--fast", "--duration", "5", "--view", "none"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"not a {base}" in err


def test_the_shipped_leaf_class_is_of_its_kind():
    sc, _ = load_scenario(ROOT / "examples" / "gussets.yaml")
    assert sc.vision.leaf == "examples.leaves:TriangleLocator"
    assert leaf_problems(sc) == []
