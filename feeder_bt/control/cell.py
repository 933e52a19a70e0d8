"""The cell (thesis ``main_control``): state, scenario, and which tree is ticked.

STOPPED --start--> STARTING (set-up tree) --> RUNNING (feeding tree)
RUNNING --pause--> PAUSED --resume--> RUNNING
RUNNING/PAUSED --stop--> STOPPING (clean-up tree) --> STOPPED
any --fault--> FAULTING (clean-up tree) --> FAULT --reset--> STOPPED

Part-specific objects (locator, adjuster, trees) are built at each start and dropped at
stop, so a scenario can be switched without restarting the process (thesis 8.1.1).
"""

from __future__ import annotations

import enum
from collections.abc import Callable
from typing import Any

import py_trees
from py_trees.common import Status

from feeder_bt.behaviours.base import Ctx, Stats, init_blackboard
from feeder_bt.behaviours.board import Board
from feeder_bt.behaviours.keys import FAULTS, RETRIEVE, SPEEDS
from feeder_bt.core.clock import Clock
from feeder_bt.core.encoder import EncoderSync
from feeder_bt.core.errors import FeederError
from feeder_bt.core.jobs import Activity
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.core.parts import PartsQueue
from feeder_bt.hal.interfaces import Hal
from feeder_bt.policy.adjusters import AdjustInputs, Speeds, make_adjuster
from feeder_bt.trees import build_cleanup, build_feeding, build_setup, fast
from feeder_bt.trees.leaves import leaf_class
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.pixels import Calibration
from feeder_bt.vision.worker import VisionWorker

ESTOP = "estop"         # the cell description's e-stop input, if it has one


class CellState(enum.Enum):
    STOPPED = "STOPPED"
    STARTING = "STARTING"
    RUNNING = "RUNNING"
    PAUSED = "PAUSED"
    STOPPING = "STOPPING"
    FAULTING = "FAULTING"
    FAULT = "FAULT"


class CellCommandError(FeederError):
    """An operator command that does not fit the cell's state."""


class Cell:
    """One cell: its state, its trees, and what is its own in a process that may hold
    more than one — its blackboard (``board``) and its ticker's news (``activity``)."""

    def __init__(self, cell: CellSpec, hal: Hal, clock: Clock) -> None:
        self.cell, self.hal, self.clock = cell, hal, clock
        self.state = CellState.STOPPED
        self.scenario: Scenario | None = None
        self.ctx: Ctx | None = None
        self.root: py_trees.behaviour.Behaviour | None = None      # the tree ticked now
        self.feeding: py_trees.behaviour.Behaviour | None = None
        self.fault_reason: str | None = None
        self.encoder = EncoderSync(cell.encoder.conveyor_bits, cell.encoder.robot_bits)
        self.stats = Stats()
        self.listeners: list[Callable[[CellState, CellState], None]] = []
        self.ticks = 0
        self.version = 0
        self.auto_adjust = True     # the operator may hold the adjuster; kept across starts
        #: this cell's blackboard: its trees' keys, apart from any other cell's; code
        #: outside the trees reads it here (``board.get(key)``, ``speeds()``)
        self.board = Board()
        self.activity = Activity()  # jobs ended and cycles restarted, for the ticker

    # ------------------------------------------------------------------ commands
    def load(self, scenario: Scenario) -> None:
        """Choose the scenario to feed; only while STOPPED (thesis: switch without restart)."""
        if self.state not in (CellState.STOPPED, CellState.FAULT):
            raise CellCommandError(f"cannot switch scenario while {self.state.value}")
        if self.scenario is not None and self.scenario.name != scenario.name:
            self.hal.changeover(scenario)
        self.scenario = scenario

    def start(self) -> None:
        if self.state is not CellState.STOPPED:
            raise CellCommandError(f"cannot start while {self.state.value}")
        if self.scenario is None:
            raise CellCommandError("no scenario loaded")
        if self.estop_pressed():
            raise CellCommandError("the e-stop is pressed: release it first")
        board = self.board
        ran = self.ctx is not None          # this cell's own last run only
        held = board.get(RETRIEVE.PART) if ran else None
        phase = board.get(RETRIEVE.PHASE) if ran else None
        self.ctx = self._make_ctx(self.scenario)
        if held is not None and held.type in self.scenario.parts and (
                phase is not None or self.hal.robot.holding()):
            # stopped (an e-stop) between pick and place, or with a reply lost: the new
            # run settles with the controller and places the part first
            board.set(RETRIEVE.PART, held)
            board.set(RETRIEVE.PHASE, phase or "held")
        if self.stats.started_at is None:
            self.stats.started_at = self.clock.now()
        self.hal.motors_on()            # the operator's Start: the first SH is a person's
        self.feeding = build_feeding(self.ctx)
        self._switch(CellState.STARTING, build_setup(self.ctx))

    def pause(self) -> None:
        if self.state is not CellState.RUNNING:
            raise CellCommandError(f"cannot pause while {self.state.value}")
        self._halt_feeding()
        self._switch(CellState.PAUSED, None)
        for conv in self.hal.conveyors.values():
            conv.stop()

    def resume(self) -> None:
        if self.state is not CellState.PAUSED:
            raise CellCommandError(f"cannot resume while {self.state.value}")
        self._switch(CellState.RUNNING, self.feeding)

    def stop(self) -> None:
        if self.state in (CellState.STOPPED, CellState.STOPPING, CellState.FAULT,
                          CellState.FAULTING):
            return
        self._halt_feeding()
        self._switch(CellState.STOPPING, build_cleanup(self.ctx))

    def fault(self, reason: str) -> None:
        if self.state in (CellState.FAULT, CellState.FAULTING, CellState.STOPPED):
            return
        self.fault_reason = reason
        self.stats.emit(self.clock.now(), "fault", kind="cell", message=reason)
        self._halt_feeding()
        self._switch(CellState.FAULTING, build_cleanup(self.ctx))

    def estop_pressed(self) -> bool:
        return ESTOP in self.cell.io and bool(self.hal.io.get(ESTOP))

    def estop(self) -> None:
        """The e-stop input: every motion stops at once and the cell goes straight to
        FAULT — no clean-up tree, since nothing may move until an operator resets."""
        if self.state in (CellState.STOPPED, CellState.FAULT):
            return
        self.fault_reason = "e-stop pressed"
        self.stats.faults["estop"] += 1
        self.stats.emit(self.clock.now(), "fault", kind="estop", message=self.fault_reason)
        if self.root is not None and self.root.status is Status.RUNNING:
            self.root.stop(Status.INVALID)         # every running job cancelled
        for conv in self.hal.conveyors.values():
            conv.stop()
        self._drop_scenario_objects()
        self._switch(CellState.FAULT, None)

    def reset(self) -> None:
        """Operator acknowledges a FAULT."""
        if self.state is not CellState.FAULT:
            raise CellCommandError(f"nothing to reset while {self.state.value}")
        if self.estop_pressed():
            raise CellCommandError("the e-stop is still pressed: release it first")
        if self.fault_reason == "e-stop pressed":
            self.stats.recovered(self.clock.now(), "estop")
        for conv in self.hal.conveyors.values():
            conv.servo(True)            # the operator's reset: motors on again
        self.fault_reason = None
        self.stats.failed_picks_in_a_row.clear()    # the operator has looked at the robot
        self._switch(CellState.STOPPED, None)

    def set_speeds(self, **speeds: float) -> None:
        """Operator or tool writes speeds (``horizontal_mm_s``, ``incline_pct``,
        ``robot_speed_pct``) to the blackboard; the trees follow."""
        for key, value in speeds.items():
            self.board.set(SPEEDS.of(key), float(value))
        self.version += 1

    def speeds(self) -> dict[str, float | None]:
        """The speeds the trees follow now, by short name (None before the first start)."""
        out: dict[str, float | None] = {}
        for key in SPEEDS.ALL:
            v = self.board.get(key)
            out[key.rsplit("/", 1)[1]] = None if v is None else float(v)
        return out

    def set_auto_adjust(self, engaged: bool) -> None:
        """Engage or hold the auto-adjuster: held, it leaves the speeds where the operator
        put them (thesis Figure 4-4's switch); the adjust tree still samples."""
        self.auto_adjust = bool(engaged)
        self.version += 1

    # ------------------------------------------------------------------ ticking
    def tick(self) -> None:
        """One tick of whichever tree the state calls for; the jobs that end in it are
        this cell's news (``activity``)."""
        with self.activity.counting():
            self._tick()

    def _tick(self) -> None:
        self.ticks += 1
        if self.state not in (CellState.STOPPED, CellState.FAULT) and self.estop_pressed():
            self.estop()
        root = self.root
        if root is None:
            return
        fast.tick_once(root)     # py_trees' tick, without its generators
        if self.state is CellState.RUNNING:
            reason = self.board.get(FAULTS.ESCALATE)
            if reason:
                self.fault(reason)
            return
        if root.status is Status.SUCCESS:
            nxt = {CellState.STARTING: (CellState.RUNNING, self.feeding),
                   CellState.STOPPING: (CellState.STOPPED, None),
                   CellState.FAULTING: (CellState.FAULT, None)}.get(self.state)
            if nxt:
                if nxt[0] in (CellState.STOPPED, CellState.FAULT):
                    self._drop_scenario_objects()
                self._switch(*nxt)
        elif root.status is Status.FAILURE:
            what = getattr(_failed_leaf(root), "feedback_message", "") or "failed"
            if self.state is CellState.STARTING:
                self.fault(f"set-up failed: {what}")
            else:   # clean-up failed: nothing more can be done in software
                first = f"{self.fault_reason}; then " if self.fault_reason else ""
                self.fault_reason = f"{first}clean-up failed: {what}"
                self._drop_scenario_objects()
                self._switch(CellState.FAULT, None)

    def nodes(self) -> list[py_trees.behaviour.Behaviour]:
        return list(self.root.iterate()) if self.root is not None else []

    # ------------------------------------------------------------------ internals
    #: what a restart of the same job carries over from its last run, as ``stats`` is: the
    #: learnt model of the arm and the account of its time (the arm has not changed), the
    #: recipe's watch (told of the restart, if it has a ``restarted``)
    KEPT_ON_RESTART = ("robot_fit", "recipe_watch")

    def _make_ctx(self, scenario: Scenario) -> Ctx:
        init_blackboard(scenario, self.board)
        kept: dict[str, Any] = {}
        if self.stats.scenario != scenario.name:   # a restart of the same job keeps counting
            self.stats = Stats()
            self.stats.scenario = scenario.name
        elif self.ctx is not None:
            kept = {k: self.ctx.extras[k] for k in self.KEPT_ON_RESTART if k in self.ctx.extras}
            for thing in kept.values():
                if hasattr(thing, "restarted"):
                    thing.restarted()
        self.stats.pending.clear()
        self.stats.attempts.clear()
        queue = PartsQueue(list(scenario.parts))
        locator_cls = leaf_class(scenario, "vision.leaf") or Locator
        locator = locator_cls(scenario.vision, scenario.parts,
                              Calibration(self.cell.camera.calibration))
        locator.prepare((self.cell.camera.height_px, self.cell.camera.width_px))
        leaf_adjuster = leaf_class(scenario, "adjust.leaf")
        adjuster = (leaf_adjuster(scenario.adjust.params)
                    if leaf_adjuster is not None
                    else make_adjuster(scenario.adjust.algorithm, scenario.adjust.params))
        ctx = Ctx(hal=self.hal, clock=self.clock, scenario=scenario, cell=self.cell,
                  queue=queue, encoder=self.encoder, stats=self.stats,
                  vision=VisionWorker(locator, self.clock, self.cell.camera.vision_latency_s),
                  adjuster=_Holdable(adjuster, self), board=self.board,
                  activity=self.activity)
        ctx.extras.update(kept)
        return ctx

    def _halt_feeding(self) -> None:
        if self.root is not None and self.root.status is Status.RUNNING:
            self.root.stop(Status.INVALID)         # terminate(): every running job cancelled
        if self.ctx is not None:
            self.ctx.queue.wake_all()

    def _drop_scenario_objects(self) -> None:
        if self.ctx is not None:
            self.ctx.queue.flush()
            self.ctx.queue.wake_all()
            self.ctx.vision.close()
        self.feeding = None

    def _switch(self, state: CellState, root: py_trees.behaviour.Behaviour | None) -> None:
        old, self.state, self.root = self.state, state, root
        self.version += 1
        self.stats.emit(self.clock.now(), "state", old=old.value, new=state.value)
        for fn in self.listeners:
            fn(old, state)

    def summary(self) -> dict[str, Any]:
        s = self.stats
        return {"state": self.state.value, "scenario": self.scenario.name if self.scenario else None,
                "retrieved": dict(s.retrieved), "queue": len(self.ctx.queue) if self.ctx else 0}


class _Holdable:
    """The scenario's adjuster, passed through unless the operator holds it."""

    def __init__(self, inner: Any, cell: Cell) -> None:
        self.inner, self.cell = inner, cell

    def update(self, inp: AdjustInputs) -> Speeds:
        if self.cell.auto_adjust:
            return self.inner.update(inp)
        return Speeds(inp.horizontal_mm_s, inp.incline_pct, inp.robot_speed_pct)

    def __getattr__(self, name: str) -> Any:      # params, NAME, ...: the adjuster's own
        if name in ("inner", "cell"):
            raise AttributeError(name)
        return getattr(self.inner, name)


def _failed_leaf(root: py_trees.behaviour.Behaviour) -> py_trees.behaviour.Behaviour:
    for node in root.iterate():
        if node.status is Status.FAILURE and not node.children:
            return node
    return root
