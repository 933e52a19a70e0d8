"""Assemble the feeding tree (four branches ticked in parallel) and the set-up and
clean-up sequences the cell runs around it."""

from __future__ import annotations

from collections.abc import Iterator

import py_trees
from py_trees.common import ParallelPolicy, Status
from py_trees.composites import Parallel, Selector, Sequence
from py_trees.decorators import SuccessIsRunning

from feeder_bt.behaviours.base import Ctx, ErrorIs, Wait
from feeder_bt.behaviours.keys import RETRIEVE
from feeder_bt.behaviours.locate import GrabGolden
from feeder_bt.behaviours.plate import InitPlate, PurgePlate, init_plate_keys
from feeder_bt.behaviours.present import StopConveyors
from feeder_bt.behaviours.retrieve import MoveSafe, PhaseIs, Reconcile, Recover, SetRobotSpeed
from feeder_bt.behaviours.setup import ClearWindow, SetSignal, SyncEncoders
from feeder_bt.core.jobs import Activity
from feeder_bt.trees import adjust, fast, locate, plate, present, retrieve

SETTLE_S = 0.25        # after the conveyors stop, before the encoders are tied together


class Loop(SuccessIsRunning):
    """Runs a branch forever, and a branch that ends a cycle starts the next in the same
    tick: with a plain success-is-running loop every cycle lost one tick between its last
    step and its first (20 ms a pick-and-place at 50 Hz, ~3 % of a lens cycle).

    Each restart is counted on the cell's ``Activity`` (the one given, else the one
    counting): a cycle's end is news to the other branches (new speeds on the blackboard),
    so the ticker must not skip the next tick."""

    def __init__(self, name: str, child: py_trees.behaviour.Behaviour,
                 activity: Activity | None = None) -> None:
        super().__init__(name, child)
        self.activity = activity

    def tick(self) -> Iterator[py_trees.behaviour.Behaviour]:
        if self.status != Status.RUNNING:
            self.initialise()
        yield from self.decorated.tick()
        if self.decorated.status == Status.SUCCESS:
            activity = self.activity or Activity.current()
            if activity is not None:
                activity.loop_restarts += 1
            yield from self.decorated.tick()      # once: a tick stays bounded
        new_status = self.update()
        if new_status != Status.RUNNING:
            self.stop(new_status)
        self.status = new_status
        yield self

    def fast_tick(self) -> None:
        """``tick`` without generators (``trees.fast``): the same steps."""
        if self.status != Status.RUNNING:
            self.initialise()
        fast.tick_child(self.decorated)
        if self.decorated.status == Status.SUCCESS:
            activity = self.activity or Activity.current()
            if activity is not None:
                activity.loop_restarts += 1
            fast.tick_child(self.decorated)
        new_status = self.update()
        if new_status != Status.RUNNING:
            fast.stop(self, new_status)
        self.status = new_status


def build_feeding(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """Four branches that never end: each absorbs its own failures (recovery fallbacks) and
    reports what it cannot handle on ``/faults/escalate``, so the Parallel never fails."""
    if plate.is_plate(ctx):
        init_plate_keys(ctx.board)
    branches = [present.build(ctx), locate.build(ctx), retrieve.build(ctx), adjust.build(ctx)]
    return Parallel("feeder", policy=ParallelPolicy.SuccessOnAll(synchronise=False),
                    children=[Loop(f"{b.name} loop", b, ctx.activity) for b in branches])


def build_setup(ctx: Ctx, robot: bool = True) -> py_trees.behaviour.Behaviour:
    """``robot=False``: the robot is its own master (the part server) and is left alone."""
    vision = ctx.scenario.vision
    steps: list[py_trees.behaviour.Behaviour] = [
        SetRobotSpeed("robot speed", ctx),
        # an e-stop can come between a servo time-out and its recovery: recover first
        _robot_to_safe(ctx),
    ] if robot else []
    steps.append(StopConveyors("stop conveyors", ctx))
    if plate.is_plate(ctx):          # nothing is accepted before the plate is homed
        steps.append(InitPlate("home the plate", ctx))
    if vision.backlight:
        steps.append(SetSignal("backlight on", ctx, "backlight", True))
    if vision.golden_image:         # a plate is cleared by a purge
        clear = (PurgePlate("clear the plate", ctx) if plate.is_plate(ctx)
                 else ClearWindow("clear the window", ctx))
        steps += [clear, GrabGolden("golden image", ctx)]
    # the belt must be at rest, and a real controller's cached counts fresh, for the sync
    steps += [Wait("belt at rest", ctx, SETTLE_S), SyncEncoders("sync encoders", ctx)]
    return Sequence("set-up" if robot else "set-up (part server)", memory=True,
                    children=steps)


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


def build_cleanup(ctx: Ctx, robot: bool = True) -> py_trees.behaviour.Behaviour:
    """``robot=False``: the robot is its own master (the part server) and is left alone."""
    steps: list[py_trees.behaviour.Behaviour] = [
        _patiently(lambda: StopConveyors("stop conveyors", ctx), ctx)]
    if ctx.scenario.vision.backlight:
        steps.append(_patiently(lambda: SetSignal("backlight off", ctx, "backlight", False),
                                ctx))
    if not robot:
        return Sequence("clean-up (part server)", memory=True, children=steps)
    steps.append(_patiently(lambda: _settle_part(ctx), ctx))
    steps.append(_patiently(lambda: _robot_to_safe(ctx), ctx))
    return Sequence("clean-up", memory=True, children=steps)


def _settle_part(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """A pick or place cut short by the stop: the controller finishes a motion it has
    started, so ask it where the part went (placed: counted; still held: the next start
    places it first)."""
    return Selector("settle the part", memory=True, children=[
        PhaseIs("nothing pending?", ctx, None),
        Reconcile("what does the gripper hold?", ctx)])


def _robot_to_safe(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    """A stop can come between a servo time-out and its recovery: power is off then, and
    the robot moves only after the recovery program has run."""
    return Selector("robot to safe", memory=True, children=[
        MoveSafe("move to safe", ctx),
        Sequence("recover first", memory=True, children=[
            ErrorIs("servo time-out?", ctx, RETRIEVE.ERROR, ("servo_timeout",)),
            Recover("run recovery program", ctx),
            MoveSafe("move to safe", ctx)])])
