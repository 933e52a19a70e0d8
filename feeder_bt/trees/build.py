"""Assemble the feeding tree (four branches ticked in parallel) and the set-up and
clean-up sequences the cell runs around it."""

from __future__ import annotations

import py_trees
from py_trees.common import ParallelPolicy
from py_trees.composites import Parallel, Sequence
from py_trees.decorators import SuccessIsRunning

from ..behaviours.common import Ctx, Wait
from ..behaviours.locate import GrabGolden
from ..behaviours.present import StopConveyors
from ..behaviours.retrieve import MoveSafe, SetRobotSpeed
from ..behaviours.setup import ClearWindow, SetSignal, SyncEncoders
from . import adjust, locate, present, retrieve

SETTLE_S = 0.25        # after the conveyors stop, before the encoders are tied together


def build_feeding(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """Four branches that never end: each absorbs its own failures (recovery fallbacks) and
    reports what it cannot handle on ``/faults/escalate``, so the Parallel never fails."""
    branches = [present.build(ctx), locate.build(ctx), retrieve.build(ctx), adjust.build(ctx)]
    return Parallel("feeder", policy=ParallelPolicy.SuccessOnAll(synchronise=False),
                    children=[SuccessIsRunning(f"{b.name} loop", b) for b in branches])


def build_setup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    vision = ctx.scenario.vision
    steps: list[py_trees.behaviour.Behaviour] = [
        SetRobotSpeed("robot speed", ctx),
        MoveSafe("robot clear of the belt", ctx),
        StopConveyors("stop conveyors", ctx),
    ]
    if vision.backlight:
        steps.append(SetSignal("backlight on", ctx, "backlight", True))
    if vision.golden_image:
        steps += [ClearWindow("clear the window", ctx), GrabGolden("golden image", ctx)]
    # the belt must be at rest, and a real controller's cached counts fresh, for the sync
    steps += [Wait("belt at rest", ctx, SETTLE_S), SyncEncoders("sync encoders", ctx)]
    return Sequence("set-up", memory=True, children=steps)


def build_cleanup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    steps: list[py_trees.behaviour.Behaviour] = [StopConveyors("stop conveyors", ctx)]
    if ctx.scenario.vision.backlight:
        steps.append(SetSignal("backlight off", ctx, "backlight", False))
    steps.append(MoveSafe("robot to safe", ctx))
    return Sequence("clean-up", memory=True, children=steps)
