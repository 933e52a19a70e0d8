"""present: run the conveyors (continuous) or serve advance requests (incremental)."""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence

from ..behaviours.common import CountFault, Ctx, Escalate, Wait
from ..behaviours.present import RunConveyors, ServeAdvance, StopConveyors


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    if ctx.scenario.present.mode == "continuous":
        work = RunConveyors("run conveyors", ctx)
    else:
        work = ServeAdvance("advance on request", ctx)
    recover = Sequence("conveyor recovery", memory=True, children=[
        CountFault("count conveyor fault", ctx, "/present/error"),
        StopConveyors("stop conveyors", ctx),
        Wait("let it settle", ctx, 1.0),
    ])
    return Selector("present", memory=True, children=[
        work, recover,
        Escalate("conveyors failed", ctx, "/present/error", "conveyors do not respond"),
    ])
