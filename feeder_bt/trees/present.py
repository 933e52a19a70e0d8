"""present: run the conveyors (continuous) or serve advance requests (incremental).

Recovery: a dropped link to the conveyor controller is retried with back-off; a jam is
shaken loose once, and a second jam within a minute goes to the operator (FAULT); a card
fault (the conveyor controller's own programs stopped) goes to the operator at once."""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence
from py_trees.decorators import Inverter

from feeder_bt.behaviours.base import CountFault, Ctx, ErrorIs, Escalate, Retry, Wait
from feeder_bt.behaviours.keys import PRESENT
from feeder_bt.behaviours.present import RunConveyors, ServeAdvance, Shake, StopConveyors
from feeder_bt.trees import plate
from feeder_bt.trees.branches import link_lost, once_a_minute

KEY = PRESENT.ERROR


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    if plate.is_plate(ctx):          # a vibratory plate serves plate actions
        return plate.build_present(ctx)
    if ctx.scenario.present.mode == "continuous":
        work = RunConveyors("run conveyors", ctx)
    else:
        work = ServeAdvance("advance on request", ctx)
    link = link_lost(ctx, KEY)
    jam = once_a_minute(
        ctx, KEY, ("jam", "jammed?", "count jam", "shake once", "shake it loose",
                   "first jam in a minute?", "jammed again"), ("conveyor",),
        [Shake("shake", ctx), Wait("let it settle", ctx, 0.5)],
        "conveyor jammed again within a minute of a shake")
    # the controller's own programs stopped: neither a shake nor a retry can help
    card = Sequence("card fault", memory=True, children=[
        ErrorIs("card fault?", ctx, KEY, ("card_fault",)),
        CountFault("count card fault", ctx, KEY),
        Escalate("to the operator", ctx, KEY, "conveyor controller failed"),
    ])
    other = Sequence("conveyor recovery", memory=True, children=[
        Inverter("not handled above",
                 ErrorIs("jam, card or link?", ctx, KEY, ("conveyor", "card_fault", "comms_lost"))),
        CountFault("count conveyor fault", ctx, KEY),
        StopConveyors("stop conveyors", ctx),
        Retry("settle and retry", ctx, KEY, first_s=1.0, max_attempts=3),
    ])
    return Selector("present", memory=True, children=[
        work, link, jam, card, other,
        Escalate("conveyors failed", ctx, KEY, "conveyors do not respond"),
    ])
