"""locate: latched grab every frame_spacing_mm of belt (or on request), recipe, enqueue.

Recovery: a dropped link is retried with back-off; a failed grab is retried once, then
the golden image is taken again on a cleared belt, then the operator is called (FAULT)."""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence

from feeder_bt.behaviours.base import AttemptsBelow, CountFault, Ctx, ErrorIs, Escalate, Retry
from feeder_bt.behaviours.keys import LOCATE
from feeder_bt.behaviours.locate import (
    AdvanceIfNothing,
    ClearForGolden,
    Enqueue,
    Grab,
    GrabGolden,
    QueueEmpty,
    Recognise,
    WaitTravel,
)
from feeder_bt.behaviours.plate import AskPlate
from feeder_bt.trees import plate
from feeder_bt.trees.branches import link_lost
from feeder_bt.trees.leaves import leaf_class

KEY = LOCATE.ERROR


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    # a scenario may replace the recipe step with a leaf class of its own (locate.leaf)
    recipe = leaf_class(ctx.scenario, "locate.leaf") or Recognise
    if ctx.scenario.present.mode == "continuous" and not plate.is_plate(ctx):
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
            # a plate: the adjuster plans a plate action instead
            AskPlate("plate action if nothing", ctx) if plate.is_plate(ctx)
            else AdvanceIfNothing("advance if nothing", ctx),
        ])
    link = link_lost(ctx, KEY)
    grab_failed = Sequence("grab failed", memory=True, children=[
        ErrorIs("camera fault?", ctx, KEY, ("grab_failed", "hal")),
        CountFault("count grab fault", ctx, KEY),
        Retry("back off", ctx, KEY, first_s=0.2, max_attempts=2),
        Selector("retry or new golden image", memory=True, children=[
            AttemptsBelow("first failure?", ctx, KEY, 2),
            Sequence("new golden image", memory=True, children=[
                ClearForGolden("clear the belt", ctx),
                GrabGolden("golden image", ctx),
            ]),
        ]),
    ])
    return Selector("locate", memory=True, children=[
        frame, link, grab_failed,
        Escalate("vision failed", ctx, KEY, "camera or vision failed"),
    ])
