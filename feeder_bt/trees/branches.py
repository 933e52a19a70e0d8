"""Recovery branches every tree shares: one definition, so a change to how a lost link is
retried reaches the belt and the plate, the camera and the robot alike."""

from __future__ import annotations

import py_trees
from py_trees.composites import Sequence

from ..behaviours.common import CountFault, Ctx, ErrorIs, Retry


def link_lost(ctx: Ctx, key: str,
              *after: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
    """A lost link: count it, reconnect with back-off, then ``after`` (e.g. a settle)."""
    return Sequence("link lost", memory=True, children=[
        ErrorIs("link lost?", ctx, key, ("comms_lost",)),
        CountFault("count link fault", ctx, key),
        Retry("reconnect (back-off)", ctx, key),
        *after,
    ])
