"""The branches of a vibratory-plate cell that differ from a belt cell's.

*present* serves plate actions instead of belt advances and recovers the plate's drive
faults: a servo error or error state is reset and the plate homed again, as the AnyFeeder
Guide allows ("Error must be reset before operation can continue", Table 3-5); a second
within a minute, or a reset that fails, goes to the operator (FAULT) with the manual's
words. *adjust* is smart feeding: judge each look that found nothing new and plan the next
plate action. *locate* and *retrieve* keep the belt cell's trees (incremental mode, static
picks), with ``AskPlate`` for ``AdvanceIfNothing``.
"""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence

from feeder_bt.behaviours.base import Ctx, Escalate
from feeder_bt.behaviours.keys import PRESENT
from feeder_bt.behaviours.plate import (
    ChoosePlateAction,
    InitPlate,
    ResetPlate,
    ServePlate,
    WaitLook,
)
from feeder_bt.trees.branches import link_lost, once_a_minute

KEY = PRESENT.ERROR


def is_plate(ctx: Ctx) -> bool:
    return ctx.cell.presentation == "plate"


def build_present(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    work = ServePlate("run plate actions", ctx)
    link = link_lost(ctx, KEY)
    drive = once_a_minute(
        ctx, KEY, ("plate drive fault", "servo or drive error?", "count plate fault",
                   "reset once a minute", "reset and home", "first in a minute?",
                   "again within a minute"), ("plate",),
        [ResetPlate("reset the error", ctx), InitPlate("home the plate", ctx)],
        lambda: f"plate feeder: {ctx.stats.counted.get(KEY)}; again within a minute of a "
                "reset")
    return Selector("present", memory=True, children=[
        work, link, drive, Escalate("plate failed", ctx, KEY, "plate feeder does not respond"),
    ])


def build_adjust(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    wait = WaitLook("a look to judge?", ctx)
    return Sequence("adjust", memory=True, children=[
        wait, ChoosePlateAction(f"smart feeding ({ctx.scenario.present.plate.policy})", ctx,
                                wait)])
