"""The public API (``feeder_bt.api``) is what code outside the package imports: the examples
and every Python block of the docs import nothing else of feeder_bt, and every name the API
promises imports."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import feeder_bt.api as api

ROOT = Path(__file__).resolve().parents[2]


def _feeder_imports(source: str) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("feeder_bt"):
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("feeder_bt")}
    return out


def test_every_promised_name_imports_once():
    assert len(api.__all__) == len(set(api.__all__))
    missing = [n for n in api.__all__ if not hasattr(api, n)]
    assert missing == []
    assert {"Locator", "Pick", "Recognise", "Adjuster", "Hal", "RunReport"} <= set(api.__all__)


def test_the_examples_import_only_the_api():
    found = {p.name: _feeder_imports(p.read_text()) for p in (ROOT / "examples").rglob("*.py")}
    assert found["leaves.py"] == {"feeder_bt.api"}
    assert {name: mods for name, mods in found.items() if mods - {"feeder_bt.api"}} == {}


def test_every_python_block_of_the_docs_imports_only_the_api():
    blocks = []
    for doc in sorted([*(ROOT / "docs").glob("*.md"), ROOT / "README.md"]):
        for block in re.findall(r"```python\n(.*?)```", doc.read_text(), flags=re.S):
            blocks.append((doc.name, _feeder_imports(block)))
    assert any(mods for _, mods in blocks)          # the docs do show the API in use
    assert [(d, m) for d, m in blocks if m - {"feeder_bt.api"}] == []


def test_a_leaf_base_of_the_api_is_the_class_the_trees_check():
    assert api.LEAF_BASES["retrieve.leaf"] is api.Pick
    assert api.LEAF_BASES["vision.leaf"] is api.Locator
