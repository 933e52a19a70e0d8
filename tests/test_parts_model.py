"""Issue 27: parts as they are — the part model against the recipe and the cell."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _scenario(tmp_path: Path, name: str, *edits: tuple[str, str]) -> Path:
    text = (ROOT / "scenarios" / name).read_text()
    text = text.replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new)
    p = tmp_path / name
    p.write_text(text)
    return p


def test_check_names_a_class_whose_area_range_cannot_hold_its_outline(tmp_path, capsys):
    """A lens given in inches (``diameter_mm: 2``): exit 2, naming the class and both
    areas, and that every lens would be too small."""
    p = _scenario(tmp_path, "lenses.yaml", ("diameter_mm: 50.8", "diameter_mm: 2"))
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if "vision.classes[0].area_mm2" in ln)
    assert "lens/flat" in line and "[1800, 2300]" in line and "3.138 mm²" in line
    assert "min_area_mm2" in err and "too small" in err


def test_check_accepts_the_shipped_scenarios(capsys):
    files = sorted(str(p) for p in (ROOT / "scenarios").glob("*.yaml"))
    assert main(["check", *files]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("edit", [("area_mm2: [550, 900]", "area_mm2: [3000, 4000]"),
                                  ("area_mm2: [1800, 2300]", "area_mm2: [100, 900]")])
def test_check_names_either_end_of_a_range_that_misses(tmp_path, capsys, edit):
    p = _scenario(tmp_path, "lenses.yaml", edit)
    assert main(["check", str(p)]) == 2
    assert "cannot hold" in capsys.readouterr().err
