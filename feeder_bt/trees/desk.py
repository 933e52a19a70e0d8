"""The trees of a cell whose robot is the master (``feeder run --part-server``).

Present, locate and adjust are the same branches as in ``build_feeding``; the retrieve
branch is replaced by the part server's side of the exchange (``ServeRobots``): robots
ask, the cell hands out parts, and each part handed out stays on the desk's record until
reported or timed out (behaviours/serve.py). The set-up and clean-up leave the robot
alone: it belongs to its own controller now, which may be in the middle of a cycle."""

from __future__ import annotations

import py_trees
from py_trees.common import ParallelPolicy
from py_trees.composites import Parallel

from feeder_bt.behaviours.base import Ctx
from feeder_bt.behaviours.desk import Desk, ServeRobots
from feeder_bt.trees import adjust, locate, present
from feeder_bt.trees.build import Loop, build_cleanup, build_setup


def build_serving(ctx: Ctx, desk: Desk) -> py_trees.behaviour.Behaviour:
    """Four branches that never end, as in ``build_feeding``; the third serves robots."""
    branches = [present.build(ctx), locate.build(ctx),
                ServeRobots("serve robots", ctx, desk), adjust.build(ctx)]
    return Parallel("feeder (part server)",
                    policy=ParallelPolicy.SuccessOnAll(synchronise=False),
                    children=[Loop(f"{b.name} loop", b, ctx.activity) for b in branches])


def build_serving_setup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """``build_setup`` without the robot steps."""
    return build_setup(ctx, robot=False)


def build_serving_cleanup(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """``build_cleanup`` without the robot steps."""
    return build_cleanup(ctx, robot=False)
