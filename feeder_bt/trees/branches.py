"""Recovery branches the trees share: one definition, so a change to how a lost link is
retried reaches the belt and the plate, the camera and the robot alike, and a device fault
recovered once a minute (a jam's shake, a plate's reset) escalates the same way."""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Sequence as Seq

import py_trees
from py_trees.composites import Selector, Sequence

from feeder_bt.behaviours.base import CountFault, Ctx, ErrorIs, Escalate, Retry
from feeder_bt.behaviours.present import FirstJamIn


def link_lost(ctx: Ctx, key: str,
              *after: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
    """A lost link: count it, reconnect with back-off, then ``after`` (e.g. a settle)."""
    return Sequence("link lost", memory=True, children=[
        ErrorIs("link lost?", ctx, key, ("comms_lost",)),
        CountFault("count link fault", ctx, key),
        Retry("reconnect (back-off)", ctx, key),
        *after,
    ])


def once_a_minute(ctx: Ctx, key: str, names: Seq[str], kinds: tuple[str, ...],
                  steps: Seq[py_trees.behaviour.Behaviour],
                  again: str | Callable[[], str]) -> py_trees.behaviour.Behaviour:
    """A device fault of ``kinds``: count it and recover with ``steps`` if it is the first
    in a minute, else go to the operator with ``again``. ``names``: the branch, its
    question, its count, the choice, the recovery, its first-in-a-minute check and the
    escalation (the belt's jam and the plate's drive fault name them their own way)."""
    branch, asked, count, choice, recovery, first, escalate = names
    return Sequence(branch, memory=True, children=[
        ErrorIs(asked, ctx, key, kinds),
        CountFault(count, ctx, key),
        Selector(choice, memory=True, children=[
            Sequence(recovery, memory=True, children=[FirstJamIn(first, ctx), *steps]),
            Escalate(escalate, ctx, key, again),
        ]),
    ])
