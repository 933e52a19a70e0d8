"""retrieve: next part by policy, too-far check, pick (tracking), place, with recovery.

Recovery (thesis 8.2.1.1, hierarchical error handling): a missed grab or an unreachable
part is counted and skipped; a servo time-out runs the controller's recovery program,
re-enables power, moves clear and finishes the part once (a part still held is placed,
else the pick is retried); a dropped link is retried with back-off, then the controller is
asked what the gripper holds (``Reconcile``): a part it gripped or released while its
reply was lost is placed or counted where it really is. Only a part no pick of this run
gripped, or what cannot be recovered, goes to the operator (FAULT)."""

from __future__ import annotations

import py_trees
from py_trees.composites import Selector, Sequence
from py_trees.decorators import Inverter

from feeder_bt.behaviours.base import CountFault, Ctx, ErrorIs, Escalate
from feeder_bt.behaviours.keys import RETRIEVE
from feeder_bt.behaviours.retrieve import (
    FailedPicksBelow,
    FollowRobotSpeed,
    Holding,
    MoveSafe,
    NextPart,
    PhaseIs,
    Pick,
    Place,
    Reconcile,
    Recover,
)
from feeder_bt.trees.branches import link_lost
from feeder_bt.trees.leaves import leaf_class

KEY = RETRIEVE.ERROR
UNKNOWN_PART = "the gripper holds a part this run did not pick: remove it"
# never recovered by software: a guard or e-stop that resets itself must not give the arm
# its power back (errors.PowerOff)
POWER_OFF = ("robot power off (an e-stop or a guard): no software recovery; release it, "
             "turn arm power on at the controller, then reset the cell")


def _failed_picks(ctx: Ctx) -> str:
    ptype, n = ctx.stats.failed_picks_in_a_row.most_common(1)[0]
    # the part's own pick point first: a ring gripped at its centroid (in its hole) misses
    # every pick however right the robot is (``feeder check`` names it before the run)
    return (f"{n} picks of {ptype} failed one after another with none placed: check "
            f"{ptype}'s pick point (parts.{ptype}.pick: on the material, not in a hole), the "
            f"robot frame (robot.base_mm, base_deg, frame_file), the camera's calibration "
            f"and the gripper")


def _place_held(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    return Sequence("place the held part", memory=True, children=[
        Holding("holding a part?", ctx), Place("place", ctx)])


def _settle(ctx: Ctx, name: str) -> py_trees.behaviour.Behaviour:
    """Ask the controller what it holds, and place the part if it is ours."""
    return Sequence(name, memory=True, children=[
        Reconcile("what does the gripper hold?", ctx),
        Selector("place it if held", memory=True, children=[
            Inverter("not held?", PhaseIs("held?", ctx, "held")),
            Place("place", ctx)])])


def _failed_pick(ctx: Ctx, name: str, kind: str, counter: str) -> py_trees.behaviour.Behaviour:
    """Count a pick that failed and skip the part, unless too many failed in a row."""
    return Sequence(name, memory=True, children=[
        ErrorIs(f"{counter}?", ctx, KEY, (kind,)),
        CountFault(f"count {counter}", ctx, KEY, counter=counter),
        Selector("or too many in a row", memory=True, children=[
            FailedPicksBelow("fewer in a row than the limit?", ctx),
            Escalate("to the operator", ctx, None, lambda: _failed_picks(ctx))])])


def build(ctx: Ctx) -> py_trees.behaviour.Behaviour:
    # a scenario may replace the pick step with a leaf class of its own (retrieve.leaf)
    pick = leaf_class(ctx.scenario, "retrieve.leaf") or Pick
    pick_and_place = Sequence("pick and place", memory=True, children=[
        FollowRobotSpeed("robot speed", ctx),
        # nothing pending and the gripper empty: go on; else (a reply was lost, the cell
        # restarted with a part in the gripper) settle with the controller first
        Selector("hands free", memory=True, children=[
            Sequence("nothing pending", memory=True, children=[
                PhaseIs("nothing pending?", ctx, None),
                Inverter("not holding?", Holding("holding a part?", ctx))]),
            _settle(ctx, "settle the part")]),
        NextPart("next part", ctx),
        pick("pick", ctx),
        Place("place", ctx),
    ])
    missed = _failed_pick(ctx, "missed grab", "missed_grab", "missed")
    unreachable = _failed_pick(ctx, "out of reach", "envelope", "unreachable")
    power = Sequence("power off", memory=True, children=[
        ErrorIs("arm power off?", ctx, KEY, ("power_off",)),
        CountFault("count power off", ctx, KEY),
        Escalate("to a person", ctx, None, POWER_OFF)])
    servo = Sequence("servo recovery", memory=True, children=[
        ErrorIs("servo time-out?", ctx, KEY, ("servo_timeout",)),
        CountFault("count servo fault", ctx, KEY),
        Recover("run recovery program", ctx),
        MoveSafe("move to safe", ctx),
        Selector("finish the part once", memory=True, children=[
            _place_held(ctx),
            # (only with the hands free: a place that failed for another reason, a link
            # dropping, goes on to that fault's own branch)
            Sequence("retry", memory=True, children=[
                Inverter("hands free?", Holding("holding a part?", ctx)),
                pick("retry pick", ctx), Place("place", ctx)]),
            # the part moved on during the recovery: a miss, not a robot failure
            _failed_pick(ctx, "missed on retry", "missed_grab", "missed"),
            _failed_pick(ctx, "gone on retry", "envelope", "unreachable"),
            # a new servo fault on the retry: recover again, and let the part go; only a
            # recovery that fails goes to the operator
            Sequence("servo fault on retry", memory=True, children=[
                ErrorIs("servo time-out again?", ctx, KEY, ("servo_timeout",)),
                CountFault("count servo fault", ctx, KEY),
                Recover("run recovery program", ctx),
                MoveSafe("move to safe", ctx)]),
        ]),
    ])
    link = link_lost(ctx, KEY, _settle(ctx, "settle the part"))
    unknown = Sequence("unknown part held", memory=True, children=[
        ErrorIs("unknown part?", ctx, KEY, ("unknown_part",)),
        Escalate("to the operator", ctx, None, UNKNOWN_PART)])
    return Selector("retrieve", memory=True, children=[
        pick_and_place, missed, unreachable, power, servo, link, unknown,
        Escalate("robot failed", ctx, KEY, "robot could not recover"),
    ])
