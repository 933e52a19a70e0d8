"""Leaves of a vibratory-plate cell, where a belt leaf must differ.

The thesis's incremental mode, with the plate as the presentation sub-system: *locate*
looks at the settled plate and, when the look found nothing new, asks for a plate action
(``AskPlate``, in place of the belt's ``AdvanceIfNothing``); *adjust* chooses the action
from what the frame showed (``ChoosePlateAction``: smart feeding, ``plate_policy``);
*present* runs it on the plate (``ServePlate``, in place of ``ServeAdvance``). The
request goes over the blackboard as the belt's advance does (``/present/request``,
``/present/completed``); the look to judge and the plan over ``/plate/look`` and
``/plate/plan``.
"""

from __future__ import annotations

from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, JobLeaf, Leaf
from feeder_bt.behaviours.board import Board
from feeder_bt.behaviours.keys import LOCATE, PLATE, PLATE_INITIAL, PRESENT
from feeder_bt.core.errors import HalError, PlateFault
from feeder_bt.core.jobs import Job, JobState
from feeder_bt.hal.interfaces import PlateFeeder
from feeder_bt.policy.plate import next_actions, part_area_mm2, view_of

LOOK, PLAN = PLATE.LOOK, PLATE.PLAN


def init_plate_keys(board: Board) -> None:
    """The plate's own blackboard keys, fresh for a run (``init_blackboard`` makes the
    belt's)."""
    for key, value in PLATE_INITIAL.items():
        board.set(key, value)


def _plate(ctx: Ctx) -> PlateFeeder:
    if ctx.hal.plate is None:
        raise HalError("this cell has no plate feeder (cell presentation: plate)")
    return ctx.hal.plate


class InitPlate(JobLeaf):
    """Set-up and recovery: home the plate's drives (nothing is accepted before)."""

    fault_key = PRESENT.ERROR
    WRITES = (PRESENT.ERROR,)

    def start(self) -> Job:
        return _plate(self.ctx).init()


class PurgePlate(JobLeaf):
    """Set-up: empty the plate into the bulk container before the golden image (the
    plate's ``ClearWindow``): the longest purge the feeder takes (127, Table 3-2) is
    more than the plate's length needs; ``PURGE_REPS`` carries every part off."""

    fault_key = PRESENT.ERROR
    WRITES = (PRESENT.ERROR,)
    PURGE_REPS = 10

    def start(self) -> Job:
        return _plate(self.ctx).purge(self.PURGE_REPS)


class ResetPlate(JobLeaf):
    """Recovery: clear the drive's error ("Error must be reset before operation can
    continue", AnyFeeder Guide Table 3-5)."""

    fault_key = PRESENT.ERROR
    WRITES = (PRESENT.ERROR,)

    def start(self) -> Job:
        return _plate(self.ctx).reset()

    def on_success(self, result: object) -> Status:
        self.ctx.stats.recovered(self.ctx.now(), "plate")
        return Status.SUCCESS


class ServePlate(Leaf):
    """Wait for a request (a list of ``(action, reps)``), run its actions one after the
    other on the plate, then count it completed. A failed action fails the leaf with the
    plate's error in ``/present/error``; the request stays, to be run again after the
    recovery."""

    READS = (PRESENT.REQUEST, PRESENT.COMPLETED)
    WRITES = (PRESENT.REQUEST, PRESENT.COMPLETED, PRESENT.ERROR)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.job: Job | None = None
        self.todo: list[tuple[str, int]] = []
        self.running: tuple[str, int, float] | None = None

    def initialise(self) -> None:
        self.job, self.todo = None, []

    def _start(self, action: str, reps: int) -> Job:
        plate = _plate(self.ctx)
        self.ctx.stats.count(f"plate_{action}")
        self.ctx.stats.emit(self.ctx.now(), "plate", action=action, reps=reps)
        self.running = (action, reps, self.ctx.now())
        if action == "dispense":
            return plate.dispense(reps)
        if action in ("feed_forward", "feed_backward"):
            return plate.feed(1 if action == "feed_forward" else -1, reps)
        if action in ("flip", "flip_forward"):
            return plate.flip(reps, 1 if action == "flip_forward" else 0)
        if action == "purge":
            return plate.purge(reps)
        raise HalError(f"unknown plate action {action!r}")

    def update(self) -> Status:
        if self.job is None and not self.todo:
            request = self.bb.get(PRESENT.REQUEST)
            if not request:
                return Status.RUNNING
            self.todo = list(request)
        while True:
            if self.job is None:
                action, reps = self.todo.pop(0)
                self.job = self._start(action, reps)
            state = self.job.poll()
            if state is JobState.RUNNING:
                self.feedback_message = self.job.name
                return Status.RUNNING
            if state is not JobState.SUCCEEDED:
                err = self.job.error or PlateFault(f"{self.job.name} {state.value}")
                self.bb.set(PRESENT.ERROR, err)
                self.feedback_message = str(err)
                self.job, self.todo = None, []
                return Status.FAILURE
            self.job = None
            if self.running is not None:
                # what a twin's fit reads (tuning/twin.py): each action's time, start to
                # the feeder's done, as a real cell's log has it
                action, reps, t0 = self.running
                self.ctx.stats.emit(self.ctx.now(), "plate_done", action=action, reps=reps,
                                    dt=round(self.ctx.now() - t0, 4))
                self.running = None
            if not self.todo:
                self.ctx.stats.succeeded(PRESENT.ERROR, self.ctx.now(), None)
                self.bb.set(PRESENT.REQUEST, None)
                self.bb.set(PRESENT.COMPLETED, self.bb.get(PRESENT.COMPLETED) + 1)
                return Status.SUCCESS

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and self.job is not None and not self.job.done:
            self.job.cancel()


class AskPlate(Leaf):
    """Locate, incremental on a plate: the look found new parts — pick them; else hand the
    look to the adjuster (``/plate/look``), wait for its plan, ask the presenter to run it
    and wait until it has. Parts seen before an action moved them are forgotten then."""

    READS = (LOCATE.FOUND, PRESENT.COMPLETED, LOOK, PLAN)
    WRITES = (PRESENT.REQUEST, LOOK)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.look = 0
        self.waiting_for: int | None = None

    def initialise(self) -> None:
        self.waiting_for = None
        self.look = 0

    def update(self) -> Status:
        if self.look == 0:
            if self.bb.get(LOCATE.FOUND) > 0:
                return Status.SUCCESS
            self.look = self.bb.get(LOOK) + 1
            self.bb.set(LOOK, self.look)
            self.ctx.clock.wake_at(self.ctx.now() + 1e-3)
        if self.waiting_for is None:
            plan = self.bb.get(PLAN)
            if plan is None or plan[0] != self.look:
                return Status.RUNNING
            self.bb.set(PRESENT.REQUEST, plan[1])
            self.waiting_for = self.bb.get(PRESENT.COMPLETED) + 1
            self.ctx.clock.wake_at(self.ctx.now() + 1e-3)    # news for present: next tick
            self.feedback_message = ", ".join(f"{a} x{n}" for a, n in plan[1])
        if self.bb.get(PRESENT.COMPLETED) >= self.waiting_for:
            seen = self.ctx.extras.get("seen")
            if seen is not None:
                seen.parts = []         # the parts moved: every part is new to the next look
            return Status.SUCCESS
        return Status.RUNNING


class WaitLook(Leaf):
    """Adjust: RUNNING until the locator hands over a look to judge."""

    READS = (LOOK,)

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.judged = 0

    def update(self) -> Status:
        return Status.SUCCESS if self.bb.get(LOOK) > self.judged else Status.RUNNING


class ChoosePlateAction(Leaf):
    """Adjust (smart feeding): the next plate actions from what the look's frame showed —
    too few parts: dispense; clustered at one end: feed the other way; many unpickable:
    flip; crowded: purge (``plate_policy.next_actions``)."""

    READS = (LOOK, LOCATE.RESULT)
    WRITES = (PLAN,)

    def __init__(self, name: str, ctx: Ctx, waiter: WaitLook) -> None:
        super().__init__(name, ctx)
        self.waiter = waiter
        self.judged = 0                     # looks judged: the fixed cycle's period counts them

    def update(self) -> Status:
        look = self.bb.get(LOOK)
        self.judged += 1
        view = view_of(self.bb.get(LOCATE.RESULT), self.ctx.cell.plate,
                       part_area_mm2(self.ctx.scenario.vision))
        actions, why = next_actions(view, self.ctx.scenario.present.plate, self.judged)
        self.bb.set(PLAN, (look, actions))
        self.waiter.judged = look
        self.ctx.stats.count("plate_decisions")
        self.ctx.stats.emit(self.ctx.now(), "plate_plan", why=why,
                            actions=[a for a, _ in actions], blobs=view.blobs,
                            parts=round(view.parts, 1), pickable=view.pickable)
        self.feedback_message = why
        self.ctx.clock.wake_at(self.ctx.now() + 1e-3)
        return Status.SUCCESS
