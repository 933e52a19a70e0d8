"""Assemble the feeding tree (four branches ticked in parallel) and the set-up and
clean-up sequences the cell runs around it."""

from __future__ import annotations

import py_trees
from py_trees.common import ParallelPolicy
from py_trees.composites import Parallel, Selector, Sequence
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


def _patiently(make, ctx: Ctx, waits: tuple[float, ...] = (1.0, 2.0, 4.0)
               ) -> py_trees.behaviour.Behaviour:
    """A clean-up step tried again after growing waits: a link that drops while the cell
    stops (it comes back within seconds) must not leave the conveyors running."""
    first = make()
    tries: list[py_trees.behaviour.Behaviour] = [first]
    for i, w in enumerate(waits, 1):
        tries.append(Sequence(f"{first.name}: try {i + 1}", memory=True, children=[
            Wait(f"wait {w:g} s", ctx, w), make()]))
    return Selector(first.name, memory=True, children=tries)


def build_cleanup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    steps: list[py_trees.behaviour.Behaviour] = [
        _patiently(lambda: StopConveyors("stop conveyors", ctx), ctx)]
    if ctx.scenario.vision.backlight:
        steps.append(_patiently(lambda: SetSignal("backlight off", ctx, "backlight", False),
                                ctx))
    steps.append(_patiently(lambda: MoveSafe("robot to safe", ctx), ctx))
    return Sequence("clean-up", memory=True, children=steps)
