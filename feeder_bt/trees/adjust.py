"""adjust: every period_s, the scenario's adjuster writes new speeds, and the two belt
counters are re-checked against each other."""

from __future__ import annotations

import py_trees
from py_trees.composites import Sequence

from feeder_bt.behaviours.adjust import Adjust, CheckDrift
from feeder_bt.behaviours.base import Ctx, Wait
from feeder_bt.trees import plate


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    if plate.is_plate(ctx):          # smart feeding chooses plate actions
        return plate.build_adjust(ctx)
    return Sequence("adjust", memory=True, children=[
        Wait("period", ctx, ctx.scenario.adjust.period_s),
        Adjust(f"adjust ({ctx.scenario.adjust.algorithm})", ctx),
        CheckDrift("belt encoders agree?", ctx),
    ])
