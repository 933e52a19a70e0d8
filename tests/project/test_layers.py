"""The layers of docs/architecture.md hold: import-linter's contracts (pyproject.toml) pass on
the package, and an upward import, even one inside a function, breaks them."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LINT = Path(sys.executable).with_name("lint-imports")


def _lint(root: Path) -> subprocess.CompletedProcess:
    return subprocess.run([str(LINT), "--config", str(root / "pyproject.toml"), "--no-cache"],
                          cwd=root, env={"PYTHONPATH": str(root), "PATH": ""},
                          capture_output=True, text=True, timeout=300)


def test_the_package_keeps_every_contract():
    out = _lint(ROOT)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "Contracts: 3 kept, 0 broken." in out.stdout


def test_an_upward_import_inside_a_function_breaks_the_layers(tmp_path):
    shutil.copytree(ROOT / "feeder_bt", tmp_path / "feeder_bt",
                    ignore=shutil.ignore_patterns("__pycache__", "static"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    clock = tmp_path / "feeder_bt" / "core" / "clock.py"
    clock.write_text(clock.read_text() + "\n\ndef _peek():\n"
                     "    from feeder_bt.control.cell import Cell\n    return Cell\n")
    out = _lint(tmp_path)
    assert out.returncode == 1
    assert "layers: arrows point down BROKEN" in out.stdout
    assert "feeder_bt.core.clock -> feeder_bt.control.cell" in out.stdout


def test_a_leaf_that_imports_a_driver_breaks_the_driver_rule(tmp_path):
    shutil.copytree(ROOT / "feeder_bt", tmp_path / "feeder_bt",
                    ignore=shutil.ignore_patterns("__pycache__", "static"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    leaf = tmp_path / "feeder_bt" / "behaviours" / "present.py"
    leaf.write_text(leaf.read_text() + "\nfrom feeder_bt.hal.galil.driver import GalilController  # noqa\n")
    out = _lint(tmp_path)
    assert out.returncode == 1
    assert "never imports a concrete driver" in out.stdout and "BROKEN" in out.stdout
