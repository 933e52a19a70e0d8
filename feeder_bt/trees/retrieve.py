"""retrieve: next part by policy, too-far check, pick (tracking), place, with recovery."""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence

from ..behaviours.common import CountFault, Ctx, ErrorIs, Escalate
from ..behaviours.retrieve import FollowRobotSpeed, MoveSafe, NextPart, Pick, Place, Recover
from ..scenario.plugins import load_class

KEY = "/retrieve/error"


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    # a scenario may replace the pick step with a leaf class of its own (retrieve.leaf)
    pick = load_class(ctx.scenario.retrieve.leaf) if ctx.scenario.retrieve.leaf else Pick
    pick_and_place = Sequence("pick and place", memory=True, children=[
        FollowRobotSpeed("robot speed", ctx),
        NextPart("next part", ctx),
        pick("pick", ctx),
        Place("place", ctx),
    ])
    missed = Sequence("missed grab", memory=True, children=[
        ErrorIs("missed?", ctx, KEY, ("missed_grab",)),
        CountFault("count miss", ctx, KEY, counter="missed"),
    ])
    unreachable = Sequence("out of reach", memory=True, children=[
        ErrorIs("envelope?", ctx, KEY, ("envelope",)),
        CountFault("count unreachable", ctx, KEY, counter="unreachable"),
    ])
    servo = Sequence("servo recovery", memory=True, children=[
        ErrorIs("servo time-out?", ctx, KEY, ("servo_timeout",)),
        CountFault("count servo fault", ctx, KEY),
        Recover("run recovery program", ctx),
        MoveSafe("move to safe", ctx),
        pick("retry pick", ctx),
        Place("place", ctx),
    ])
    return Selector("retrieve", memory=True, children=[
        pick_and_place, missed, unreachable, servo,
        Escalate("robot failed", ctx, KEY, "robot could not recover"),
    ])
