"""The trees of a cell whose robot is the master (``feeder run --part-server``).

Present, locate and adjust are the same branches as in ``build_feeding``; the retrieve
branch is replaced by the part server's side of the exchange (``ServeRobots``): robots
ask, the cell hands out parts, and each part handed out stays on the desk's record until
reported or timed out (behaviours/serve.py). The set-up and clean-up leave the robot
alone: it belongs to its own controller now, which may be in the middle of a cycle."""

from __future__ import annotations

import py_trees
from py_trees.common import ParallelPolicy
from py_trees.composites import Parallel, Sequence

from ..behaviours.common import Ctx, Wait
from ..behaviours.locate import GrabGolden
from ..behaviours.present import StopConveyors
from ..behaviours.serve import Desk, ServeRobots
from ..behaviours.setup import ClearWindow, SetSignal, SyncEncoders
from . import adjust, locate, present
from .build import SETTLE_S, Loop, _patiently


def build_serving(ctx: Ctx, desk: Desk) -> py_trees.behaviour.Behaviour:
    """Four branches that never end, as in ``build_feeding``; the third serves robots."""
    branches = [present.build(ctx), locate.build(ctx),
                ServeRobots("serve robots", ctx, desk), adjust.build(ctx)]
    return Parallel("feeder (part server)",
                    policy=ParallelPolicy.SuccessOnAll(synchronise=False),
                    children=[Loop(f"{b.name} loop", b) for b in branches])


def build_serving_setup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """``build_setup`` without the robot steps."""
    vision = ctx.scenario.vision
    steps: list[py_trees.behaviour.Behaviour] = [StopConveyors("stop conveyors", ctx)]
    if vision.backlight:
        steps.append(SetSignal("backlight on", ctx, "backlight", True))
    if vision.golden_image:
        steps += [ClearWindow("clear the window", ctx), GrabGolden("golden image", ctx)]
    steps += [Wait("belt at rest", ctx, SETTLE_S), SyncEncoders("sync encoders", ctx)]
    return Sequence("set-up (part server)", memory=True, children=steps)


def build_serving_cleanup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """``build_cleanup`` without the robot steps."""
    steps: list[py_trees.behaviour.Behaviour] = [
        _patiently(lambda: StopConveyors("stop conveyors", ctx), ctx)]
    if ctx.scenario.vision.backlight:
        steps.append(_patiently(lambda: SetSignal("backlight off", ctx, "backlight", False),
                                ctx))
    return Sequence("clean-up (part server)", memory=True, children=steps)
