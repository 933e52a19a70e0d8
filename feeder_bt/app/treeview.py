"""Draw a scenario's trees without any hardware: built over the mock HAL."""

from __future__ import annotations

import re
import shutil

import py_trees

from feeder_bt.behaviours.base import Ctx, Stats, init_blackboard
from feeder_bt.config import load_scenario
from feeder_bt.core.clock import SimClock
from feeder_bt.core.encoder import EncoderSync
from feeder_bt.core.errors import FeederError
from feeder_bt.core.model import Scenario
from feeder_bt.core.parts import PartsQueue
from feeder_bt.hal.mock import MockHal
from feeder_bt.trees import build_cleanup, build_feeding, build_setup


def scenario_tree(path: str, part: str = "feeding") -> py_trees.behaviour.Behaviour:
    return _build(path, part)[1]


def _build(path: str, part: str) -> tuple[Scenario, py_trees.behaviour.Behaviour]:
    scenario, cell = load_scenario(path)
    init_blackboard(scenario)
    ctx = Ctx(hal=MockHal(), clock=SimClock(), scenario=scenario, cell=cell,
              queue=PartsQueue(list(scenario.parts)), encoder=EncoderSync(), stats=Stats())
    builder = {"feeding": build_feeding, "setup": build_setup, "cleanup": build_cleanup}[part]
    return scenario, builder(ctx)


def render_tree(path: str, fmt: str, part: str = "feeding") -> str | bytes:
    """The trees drawn as text or Graphviz; the graph is named after the scenario and the
    part drawn (``lenses_feeding``), not py_trees' default."""
    scenario, root = _build(path, part)
    if fmt == "ascii":
        return py_trees.display.ascii_tree(root)
    if fmt == "unicode":
        return py_trees.display.unicode_tree(root)
    graph = py_trees.display.dot_tree(root, with_blackboard_variables=False)
    graph.set_name(graph_name(scenario.name, part))
    if fmt == "dot":
        return graph.to_string()
    if shutil.which("dot") is None:
        raise FeederError(f"--format {fmt} needs Graphviz's `dot` program (Debian: apt-get "
                          "install graphviz); --format dot works without it")
    return graph.create(format=fmt)


def graph_name(scenario: str, part: str) -> str:
    """A Graphviz identifier: letters, digits and underscores, not starting with a digit."""
    name = re.sub(r"\W", "_", f"{scenario}_{part}")
    return name if not name[0].isdigit() else f"_{name}"
