"""``trees.fast.tick_once`` ticks a tree as py_trees' generators do: the same calls to
every behaviour in the same order, the same statuses and current children, on random trees
of every composite and decorator the cell's trees use (seeded, so each run is the same)."""

from __future__ import annotations

import random

import py_trees
import pytest
from py_trees.common import ParallelPolicy, Status
from py_trees.composites import Parallel, Selector, Sequence
from py_trees.decorators import Inverter, SuccessIsRunning

from feeder_bt.core.jobs import Activity
from feeder_bt.trees import fast
from feeder_bt.trees.build import Loop

STATUSES = (Status.SUCCESS, Status.FAILURE, Status.RUNNING)


class Scripted(py_trees.behaviour.Behaviour):
    """A leaf whose ``update`` draws its status from its own seeded stream, and which logs
    every call made to it."""

    def __init__(self, name: str, seed: int, log: list) -> None:
        super().__init__(name)
        self.rng = random.Random(seed)
        self.log = log

    def initialise(self) -> None:
        self.log.append((self.name, "initialise"))

    def update(self) -> Status:
        status = self.rng.choice(STATUSES)
        self.log.append((self.name, "update", status))
        return status

    def terminate(self, new_status: Status) -> None:
        self.log.append((self.name, "terminate", self.status, new_status))


def build(rng: random.Random, log: list, depth: int = 0) -> py_trees.behaviour.Behaviour:
    """A random tree; the same ``rng`` state builds the same tree."""
    n = rng.randrange(1_000_000)
    if depth >= 4 or rng.random() < 0.3:
        return Scripted(f"leaf {n}", n, log)
    kind = rng.choice(["seq", "seq_mem", "sel", "sel_mem", "par_all", "par_one", "par_sync",
                       "inv", "sir", "loop"])
    if kind in ("inv", "sir", "loop"):
        child = build(rng, log, depth + 1)
        if kind == "inv":
            return Inverter(f"inv {n}", child)
        if kind == "sir":
            return SuccessIsRunning(f"sir {n}", child)
        return Loop(f"loop {n}", child, Activity())
    children = [build(rng, log, depth + 1) for _ in range(rng.randint(1, 4))]
    if kind.startswith("seq"):
        return Sequence(f"seq {n}", memory=kind == "seq_mem", children=children)
    if kind.startswith("sel"):
        return Selector(f"sel {n}", memory=kind == "sel_mem", children=children)
    policy = {"par_all": ParallelPolicy.SuccessOnAll(synchronise=False),
              "par_one": ParallelPolicy.SuccessOnOne(),
              "par_sync": ParallelPolicy.SuccessOnAll(synchronise=True)}[kind]
    return Parallel(f"par {n}", policy=policy, children=children)


def snapshot(root: py_trees.behaviour.Behaviour) -> list:
    return [(node.name, node.status,
             getattr(getattr(node, "current_child", None), "name", None))
            for node in root.iterate()]


@pytest.mark.parametrize("seed", range(40))
def test_fast_tick_does_what_py_trees_does(seed):
    log_a: list = []
    log_b: list = []
    tree_a = build(random.Random(seed), log_a)
    tree_b = build(random.Random(seed), log_b)
    for _ in range(30):
        tree_a.tick_once()
        fast.tick_once(tree_b)
        assert log_b == log_a
        assert snapshot(tree_b) == snapshot(tree_a)


def test_an_unknown_tick_is_left_to_its_class():
    """A class with its own generator ``tick`` is ticked by it."""
    seen = []

    class Own(py_trees.behaviour.Behaviour):
        def tick(self):
            seen.append(self.name)
            self.status = Status.SUCCESS
            yield self

        def update(self) -> Status:
            return Status.SUCCESS

    root = Sequence("root", memory=False, children=[Own("a"), Own("b")])
    fast.tick_once(root)
    assert seen == ["a", "b"] and root.status is Status.SUCCESS
