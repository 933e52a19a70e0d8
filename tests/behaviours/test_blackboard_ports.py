"""Every leaf's ports: the blackboard keys it declares (``READS``/``WRITES``) are the keys
its client registered, and a run writes no key through a leaf that did not declare it."""

from __future__ import annotations

from pathlib import Path

import py_trees
import pytest
from py_trees.blackboard import Blackboard

from feeder_bt.app.factory import make_hal
from feeder_bt.app.treeview import scenario_tree
from feeder_bt.behaviours import keys
from feeder_bt.behaviours.base import Leaf
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell
from feeder_bt.control.ticker import Ticker

ROOT = Path(__file__).resolve().parents[2]
SCENARIOS = sorted((ROOT / "scenarios").glob("*.yaml"))


def all_keys() -> set[str]:
    """Every key constant of ``feeder_bt.behaviours.keys``."""
    out: set[str] = set()
    for ns in (keys.SPEEDS, keys.PRESENT, keys.LOCATE, keys.RETRIEVE, keys.FAULTS, keys.PLATE):
        out |= {v for k, v in vars(ns).items()
                if k.isupper() and k != "NS" and isinstance(v, str)}
    return out


@pytest.mark.parametrize("part", ["feeding", "setup", "cleanup"])
@pytest.mark.parametrize("path", SCENARIOS, ids=lambda p: p.stem)
def test_registered_keys_are_the_declared_ones(path: Path, part: str) -> None:
    known = all_keys()
    root = scenario_tree(str(path), part)
    leaves = [n for n in root.iterate() if not n.children and not
              isinstance(n, py_trees.decorators.Decorator)]
    assert leaves
    for node in leaves:
        assert isinstance(node, Leaf), f"{node.name}: not a feeder leaf"
        clients = node.blackboards
        assert len(clients) == 1, f"{node.name}: {len(clients)} blackboard clients"
        bb = clients[0]
        assert bb.read == set(node.READS), node.name
        assert bb.write == set(node.WRITES), node.name
        assert not bb.exclusive, node.name
        assert set(node.READS) | set(node.WRITES) <= known, node.name
        fault_key = getattr(node, "fault_key", None)
        assert fault_key is None or fault_key in node.WRITES, node.name


@pytest.mark.parametrize("name", ["lenses", "plate_lenses"])
def test_a_run_writes_only_declared_keys(name: str) -> None:
    """Run the cell with py_trees' activity stream on: each write by a leaf is to a key
    among its ``WRITES``, each write by anyone else is the cell's own (start, speeds)."""
    scenario, spec = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    hal, clock = make_hal("sim", scenario, spec, 1)
    cell = Cell(spec, hal, clock)
    cell.load(scenario)
    bad: list[str] = []
    writes: set[str] = set()

    def check() -> None:
        stream = Blackboard.activity_stream
        assert stream is not None
        owners: dict = {}
        for tree in (cell.root, cell.feeding):
            for node in (tree.iterate() if tree is not None else ()):
                for bb in getattr(node, "blackboards", ()):
                    owners[bb.unique_identifier] = node
        for item in stream.data:
            if item.activity_type not in ("WRITE", "INITIALISED", "ACCESS_DENIED"):
                continue
            if not item.key.startswith(cell.board.prefix + "/"):
                continue                  # not this cell's (there is no other here)
            key = item.key[len(cell.board.prefix):]
            node = owners.get(item.client_id)
            if item.activity_type == "ACCESS_DENIED":
                bad.append(f"{item.client_name}: denied {key}")
            elif node is not None:
                writes.add(key)
                if key not in node.WRITES:
                    bad.append(f"{node.name} wrote {key}, not among its WRITES")
            elif item.client_id != cell.board._writer.unique_identifier:
                bad.append(f"{item.client_name} (no leaf of the cell's trees) wrote {key}")
        stream.clear()

    Blackboard.enable_activity_stream(maximum_size=100_000)
    try:
        cell.start()
        check()
        ticker = Ticker(cell, fast=True)
        ticker.run(until=45.0, every=check)
    finally:
        Blackboard.disable_activity_stream()
        cell.stop()
        if cell.ctx is not None and cell.ctx.vision is not None:
            cell.ctx.vision.close()
    assert not bad, bad[:10]
    assert writes                                  # the leaves did write
