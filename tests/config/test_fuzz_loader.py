"""Fuzz the scenario loader with mutations of the shipped scenarios.

Whatever is done to a scenario file — a key deleted, a value replaced by some other scalar,
list or mapping, an unknown key inserted, a line cut, doubled or shifted — ``load_scenario``
either loads it or raises a ``ConfigError`` whose problems are each one line naming a file. Never
a traceback. The example budget is fixed and the examples derandomized, so CI runs the
same cases every time.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder_bt.config import load_scenario
from feeder_bt.config.loader import LEAF_RE
from feeder_bt.core.errors import ConfigError
from feeder_bt.core.model import Scenario

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted((ROOT / "scenarios").glob("*.yaml"))
FUZZ = settings(max_examples=200, derandomize=True, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture,
                                       HealthCheck.too_slow])


def _absolute_cell(path: Path) -> dict[str, Any]:
    """The scenario as data, its ``cell:`` made absolute so a copy loads from anywhere."""
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    data["cell"] = str((path.parent / data["cell"]).resolve())
    return data


BASES = [_absolute_cell(p) for p in SHIPPED]
TEXTS = [yaml.safe_dump(d, sort_keys=False) for d in BASES]


def _no_leaf(s: str) -> bool:
    # a string that looks like ``pkg.mod:Class`` would be imported by a ``leaf:`` key
    return LEAF_RE.match(s) is None


scalars = st.one_of(
    st.none(), st.booleans(), st.integers(-10**30, 10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["", "lens", "flat", "fixed", "continuous", "disc", "0", "1e3", "-1",
                     "yes", "~", "!!", "<<", "../cells/sim.yaml", "."]),
    st.text(max_size=16).filter(_no_leaf))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4),
    st.dictionaries(st.text(min_size=1, max_size=10).filter(_no_leaf), inner, max_size=3)),
    max_leaves=12)
unknown_keys = st.one_of(st.sampled_from(["nme", "parts_", "tick", "speed", "x", "leaf_",
                                          "horizontal_mm", "probabilty", "area"]),
                         st.text(min_size=1, max_size=10).filter(_no_leaf))


def _containers(node: Any, path: tuple = ()) -> list[tuple]:
    """Paths of every mapping and list in the document, in a fixed order."""
    out = [path]
    items = (node.items() if isinstance(node, dict)
             else enumerate(node) if isinstance(node, list) else ())
    for k, v in items:
        if isinstance(v, dict | list):
            out.extend(_containers(v, (*path, k)))
    return out


def _at(doc: Any, path: tuple) -> Any:
    for k in path:
        doc = doc[k]
    return doc


@st.composite
def mutated(draw) -> dict[str, Any]:
    doc = copy.deepcopy(BASES[draw(st.integers(0, len(BASES) - 1))])
    for _ in range(draw(st.integers(1, 3))):
        paths = _containers(doc)
        maps = [q for q in paths if isinstance(_at(doc, q), dict)]
        if maps and draw(st.booleans()):          # most of the meaning is in the mappings
            paths = maps
        node = _at(doc, draw(st.sampled_from(paths)))
        keys = list(node) if isinstance(node, dict) else list(range(len(node)))
        op = draw(st.sampled_from(["delete", "replace", "insert"]))
        if op == "insert" or not keys:
            if isinstance(node, dict):
                node[draw(unknown_keys)] = draw(values)
            else:
                node.insert(draw(st.integers(0, len(node))), draw(values))
        elif op == "delete":
            del node[draw(st.sampled_from(keys))]
        else:
            node[draw(st.sampled_from(keys))] = draw(values)
    return doc


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz_scenarios")


def _loads_or_one_line(path: Path) -> None:
    try:
        scenario, _ = load_scenario(path)
    except ConfigError as e:
        for problem in e.problems:            # every problem is one line naming a file
            msg = str(problem)
            assert msg and "\n" not in msg and "\r" not in msg, msg
            assert problem.file, msg
            assert msg.startswith(problem.file), msg
        assert str(e).splitlines() == e.lines()
    else:
        assert isinstance(scenario, Scenario)


def test_the_bases_load(fuzz_dir):
    for i, text in enumerate(TEXTS):
        p = fuzz_dir / f"base{i}.yaml"
        p.write_text(text, encoding="utf-8")
        load_scenario(p)


@FUZZ
@given(mutated())
def test_fuzz_mutated_scenarios(fuzz_dir, doc):
    p = fuzz_dir / "mutated.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False, allow_unicode=True), encoding="utf-8")
    _loads_or_one_line(p)


@st.composite
def mutated_text(draw) -> str:
    lines = TEXTS[draw(st.integers(0, len(TEXTS) - 1))].splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["cut", "double", "indent", "dedent", "insert", "truncate"]))
        if op == "cut" and len(lines) > 1:
            del lines[i]
        elif op == "double":
            lines.insert(i, lines[i])
        elif op == "indent":
            lines[i] = " " * draw(st.integers(1, 4)) + lines[i]
        elif op == "dedent":
            lines[i] = lines[i].lstrip()
        elif op == "truncate":
            lines[i] = lines[i][: draw(st.integers(0, max(0, len(lines[i]) - 1)))]
        else:
            lines.insert(i, draw(st.text(alphabet=" :-[]{},#&*!|>'\"%@?abc0.9\t", max_size=12)))
    return "\n".join(lines) + "\n"


@FUZZ
@given(mutated_text())
def test_fuzz_mutated_scenario_text(fuzz_dir, text):
    p = fuzz_dir / "mutated_text.yaml"
    p.write_text(text, encoding="utf-8")
    _loads_or_one_line(p)
