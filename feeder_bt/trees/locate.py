"""locate: latched grab every frame_spacing_mm of belt (or on request), recipe, enqueue."""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence

from ..behaviours.common import CountFault, Ctx, ErrorIs, Escalate, Wait
from ..behaviours.locate import AdvanceIfNothing, Enqueue, Grab, QueueEmpty, Recognise, WaitTravel
from ..scenario.plugins import load_class


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    # a scenario may replace the recipe step with a leaf class of its own (locate.leaf)
    recipe = load_class(ctx.scenario.locate.leaf) if ctx.scenario.locate.leaf else Recognise
    if ctx.scenario.present.mode == "continuous":
        frame = Sequence("frame", memory=True, children=[
            WaitTravel("wait belt travel", ctx),
            Grab("grab + latch", ctx),
            recipe("recipe", ctx),
            Enqueue("enqueue", ctx),
        ])
    else:
        frame = Sequence("look", memory=True, children=[
            QueueEmpty("queue empty?", ctx),
            Grab("grab + latch", ctx),
            recipe("recipe", ctx),
            Enqueue("enqueue", ctx),
            AdvanceIfNothing("advance if nothing", ctx),
        ])
    grab_failed = Sequence("grab failed", memory=True, children=[
        ErrorIs("camera fault?", ctx, "/locate/error", ("grab_failed", "hal")),
        CountFault("count grab fault", ctx, "/locate/error"),
        Wait("back off", ctx, 0.2),
    ])
    return Selector("locate", memory=True, children=[
        frame, grab_failed,
        Escalate("vision failed", ctx, "/locate/error", "camera or vision failed"),
    ])
