"""What every leaf shares: the context, the job-leaf pattern, timers and fault reporting.

A leaf never blocks: ``JobLeaf`` starts a HAL job in ``initialise()``, polls it in
``update()`` and cancels it in ``terminate()`` when pre-empted.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import py_trees
from py_trees.common import Status

from feeder_bt.behaviours.board import ROOT, Board
from feeder_bt.behaviours.keys import FAULTS, INITIAL, SPEEDS
from feeder_bt.core.clock import EPS, Clock
from feeder_bt.core.encoder import EncoderSync
from feeder_bt.core.errors import HalError
from feeder_bt.core.jobs import Activity, Job, JobState
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.core.parts import PartsQueue
from feeder_bt.hal.interfaces import Hal


@dataclass
class Event:
    t: float
    kind: str
    data: dict[str, Any]


class Stats:
    """Counters and samples the trees write and the adjuster, view and report read."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        self.retrieved: Counter[str] = Counter()
        self.faults: Counter[str] = Counter()
        self.recoveries: Counter[str] = Counter()
        self.vision_ms: list[float] = []
        self.timeline: list[dict[str, float]] = []
        self.events: deque[Event] = deque(maxlen=500)
        self.listeners: list = []
        self.version = 0
        self.started_at: float | None = None
        self.last_retrieved: str | None = None
        self.scenario: str | None = None
        # faults a branch is retrying through, by blackboard key, oldest first: the next
        # success of a job reporting to that key that proves a kind recovered (``recovers``)
        # is that kind's recovery; ``attempts`` counts the retries meanwhile. A key can hold
        # two: a link dropping while a failed grab is retried leaves both to recover.
        self.pending: dict[str, list[str]] = {}
        self.counted: dict[str, object] = {}      # key -> the error CountFault last counted
        self.attempts: Counter[str] = Counter()
        #: failures met while a branch retried through the same fault, by kind: each one
        #: an attempt of the same episode (``retry_failed`` events), not a new fault
        self.retried: Counter[str] = Counter()
        #: the in-run encoder re-check (``CheckDrift``): last and largest drift, samples
        self.drift: dict[str, Any] = {}
        #: picks that failed (missed, out of reach) since the last part placed, by type
        self.failed_picks_in_a_row: Counter[str] = Counter()
        #: the kit being built (kits.py; None: no kit), and each type's located parts
        #: whose path met the reach (the kit's supply bound)
        self.kit: Any = None
        self.in_reach_by_type: Counter[str] = Counter()

    def count(self, key: str, n: int = 1) -> None:
        self.counts[key] += n
        self.version += 1

    def emit(self, t: float, kind: str, /, **data: Any) -> None:
        # positional-only: fault events carry their own ``kind=`` in ``data``
        ev = Event(t, kind, data)
        self.events.append(ev)
        self.version += 1
        for fn in self.listeners:
            fn(ev)

    def retrying(self, key: str, kind: str) -> None:
        """A branch will retry past a fault of ``kind``: its next success recovers it."""
        self.recovering(key, kind)
        self.attempts[key] += 1

    def recovering(self, key: str, kind: str) -> None:
        """A fault of ``kind`` on ``key`` is being recovered (not retried: no attempt)."""
        kinds = self.pending.setdefault(key, [])
        if kind not in kinds:
            kinds.append(kind)

    def is_retrying(self, key: str, kind: str) -> bool:
        """A failure of ``kind`` now is an attempt of an episode under way, not a new fault."""
        return kind in self.pending.get(key, ())

    def recovered(self, t: float, kind: str, attempts: int = 0) -> None:
        """A fault of ``kind`` recovered: counted and logged as one, so that a report rebuilt
        from the event log (a killed run's) counts the same recoveries as the run's own."""
        self.recoveries[kind] += 1
        self.emit(t, "recovered", kind=kind, attempts=attempts)

    def succeeded(self, key: str, t: float, kinds: tuple[str, ...] | None = None) -> None:
        """A job reporting to ``key`` succeeded: the faults of ``kinds`` (any, if None)
        the branch was recovering from are recovered; the others stay pending."""
        waiting = self.pending.get(key)
        if not waiting:                         # the usual case, on every job's success
            self.attempts[key] = 0
            return
        done = [k for k in waiting if kinds is None or k in kinds]
        if not done:
            return
        for kind in done:
            self.recovered(t, kind, self.attempts[key])
        left = [k for k in waiting if k not in done]
        if left:
            self.pending[key] = left
        else:
            self.pending.pop(key, None)
        self.attempts[key] = 0                  # a success ends the retries in a row

    @property
    def total_retrieved(self) -> int:
        return sum(self.retrieved.values())


@dataclass
class Ctx:
    """Everything a leaf may use, handed down by the cell (never a concrete driver)."""

    hal: Hal
    clock: Clock
    scenario: Scenario
    cell: CellSpec
    queue: PartsQueue
    encoder: EncoderSync
    stats: Stats
    vision: Any = None                   # VisionWorker, created per scenario
    adjuster: Any = None
    extras: dict[str, Any] = field(default_factory=dict)
    #: the cell's blackboard; a tree built outside a cell uses the root one
    board: Board = field(default_factory=lambda: ROOT)
    #: the cell's news for its ticker (jobs ended, cycles restarted)
    activity: Activity = field(default_factory=Activity)

    def now(self) -> float:
        return self.clock.now()


# --------------------------------------------------------------------------- blackboard


def init_blackboard(scenario: Scenario, board: Board = ROOT) -> None:
    """Fresh blackboard for a scenario: speeds from the YAML, no faults."""
    board.reset({SPEEDS.HORIZONTAL: scenario.present.horizontal_mm_s,
                 SPEEDS.INCLINE: scenario.present.incline_pct,
                 SPEEDS.ROBOT: scenario.retrieve.robot_speed_pct, **INITIAL})


# --------------------------------------------------------------------------- leaves


class Leaf(py_trees.behaviour.Behaviour):
    """A leaf of the cell's trees.

    ``READS`` and ``WRITES`` are its ports (BehaviorTree.CPP's ``providedPorts()``): the
    blackboard keys it uses, from ``keys``. Its client (``self.bb``) is registered from
    them and nothing else, so py_trees refuses a key the leaf did not declare. A leaf whose
    key is an argument (``ErrorIs``) sets ``READS`` on the instance before this runs."""

    READS: tuple[str, ...] = ()
    WRITES: tuple[str, ...] = ()

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name)
        self.ctx = ctx
        board = getattr(ctx, "board", ROOT)     # a stand-in context (a test's) may have none
        self.bb = board.client(self, read=self.READS, write=self.WRITES)


class JobLeaf(Leaf):
    """Start a job, poll it, cancel it when pre-empted. Failures land in ``/retrieve/error``-
    style keys through ``on_failure`` so that a fallback can choose the recovery."""

    fault_key: str | None = None        # blackboard key that receives the error kind
    # fault kinds this leaf's success shows recovered (None: any): a belt notification
    # arriving says nothing about a camera that failed
    recovers: tuple[str, ...] | None = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """A leaf that reports faults to a key declares that key among its ports."""
        super().__init_subclass__(**kwargs)
        if cls.fault_key and cls.fault_key not in cls.WRITES:
            raise TypeError(f"{cls.__name__}: fault_key {cls.fault_key} is not in its WRITES")

    def __init__(self, name: str, ctx: Ctx) -> None:
        super().__init__(name, ctx)
        self.job: Job | None = None
        self.error: HalError | None = None

    def start(self) -> Job:
        raise NotImplementedError

    def on_success(self, result: Any) -> Status:
        return Status.SUCCESS

    def on_failure(self, error: HalError) -> Status:
        self.feedback_message = str(error)
        if self.fault_key:
            self.bb.set(self.fault_key, error)
        return Status.FAILURE

    def initialise(self) -> None:
        self.error = None
        self.job = self.start()

    def update(self) -> Status:
        assert self.job is not None
        state = self.job.poll()
        if state is JobState.RUNNING:
            return Status.RUNNING
        if state is JobState.SUCCEEDED:
            if self.fault_key:
                self.ctx.stats.succeeded(self.fault_key, self.ctx.now(), self.recovers)
            return self.on_success(self.job.result)
        self.error = self.job.error or HalError(f"{self.job.name} {state.value}")
        return self.on_failure(self.error)

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID and self.job is not None and not self.job.done:
            self.job.cancel()


class Wait(Leaf):
    """RUNNING for ``seconds`` of clock time; tells the clock when it will be done."""

    def __init__(self, name: str, ctx: Ctx, seconds: float) -> None:
        super().__init__(name, ctx)
        self.seconds = seconds
        self.until = 0.0

    def initialise(self) -> None:
        self.until = self.ctx.now() + self.seconds
        self.ctx.clock.wake_at(self.until)

    def update(self) -> Status:
        return Status.SUCCESS if self.ctx.now() >= self.until - EPS else Status.RUNNING


class ErrorIs(Leaf):
    """Condition: the last error in ``key`` is of one of ``kinds``."""

    def __init__(self, name: str, ctx: Ctx, key: str, kinds: tuple[str, ...]) -> None:
        self.READS = (key,)
        super().__init__(name, ctx)
        self.key, self.kinds = key, kinds

    def update(self) -> Status:
        err = self.bb.get(self.key)
        return Status.SUCCESS if err is not None and err.kind in self.kinds else Status.FAILURE


class CountFault(Leaf):
    """Count the fault in ``key``, log it, and let the branch go on. A failure while the
    branch retries through the same kind of fault is one more attempt, not a new fault."""

    def __init__(self, name: str, ctx: Ctx, key: str, counter: str | None = None) -> None:
        self.READS = (key,)
        super().__init__(name, ctx)
        self.key, self.counter = key, counter

    def update(self) -> Status:
        err = self.bb.get(self.key)
        kind = err.kind if err is not None else "unknown"
        stats = self.ctx.stats
        stats.counted[self.key] = err
        if stats.is_retrying(self.key, kind):       # the same fault, still being retried
            stats.retried[kind] += 1
            stats.emit(self.ctx.now(), "retry_failed", kind=kind, message=str(err),
                       attempt=stats.attempts[self.key])
            return Status.SUCCESS
        stats.faults[kind] += 1
        if self.counter:
            self.ctx.stats.count(self.counter)
        self.ctx.stats.emit(self.ctx.now(), "fault", kind=kind, message=str(err))
        return Status.SUCCESS


class Retry(Leaf):
    """Fallback step for a fault that may pass (a dropped link, a failed grab): count it
    as being retried and back off, longer each time; FAILURE after ``max_attempts`` in a
    row without a success, so the next fallback (escalation) runs. The branch's next
    successful job records the recovery (``Stats.succeeded``)."""

    def __init__(self, name: str, ctx: Ctx, key: str, first_s: float = 0.5,
                 max_s: float = 8.0, max_attempts: int = 8) -> None:
        self.READS = (key,)
        super().__init__(name, ctx)
        self.key, self.first_s, self.max_s, self.max_attempts = key, first_s, max_s, max_attempts
        self.until = 0.0
        self.give_up = False

    def initialise(self) -> None:
        err = self.bb.get(self.key)
        stats = self.ctx.stats
        self.give_up = stats.attempts[self.key] >= self.max_attempts
        if self.give_up:
            return
        stats.retrying(self.key, getattr(err, "kind", "hal"))
        wait = min(self.max_s, self.first_s * 2 ** (stats.attempts[self.key] - 1))
        self.until = self.ctx.now() + wait
        self.ctx.clock.wake_at(self.until)
        self.feedback_message = f"attempt {stats.attempts[self.key]}: retry in {wait:g} s"

    def update(self) -> Status:
        if self.give_up:
            self.feedback_message = f"gave up after {self.max_attempts} attempts"
            return Status.FAILURE
        return Status.SUCCESS if self.ctx.now() >= self.until - EPS else Status.RUNNING


class AttemptsBelow(Leaf):
    """Condition: fewer than ``n`` retries in a row on ``key`` (a recovery ladder's rung)."""

    def __init__(self, name: str, ctx: Ctx, key: str, n: int) -> None:
        super().__init__(name, ctx)
        self.key, self.n = key, n

    def update(self) -> Status:
        return Status.SUCCESS if self.ctx.stats.attempts[self.key] < self.n else Status.FAILURE


#: Faults that pass by themselves (a link comes back): when one strikes a recovery step,
#: the branch starts over instead of escalating, and its own fallback handles it.
TRANSIENT = ("comms_lost",)


class Escalate(Leaf):
    """Last resort of a branch: ask the cell to go to FAULT, with the reason.

    A transient fault that struck a recovery step itself (a link dropping during a shake)
    is counted and the branch starts over, up to ``Retry``'s limit of attempts in a row.
    ``what`` may be a function, for a reason that says what happened (a count, a type)."""

    WRITES = (FAULTS.ESCALATE,)

    def __init__(self, name: str, ctx: Ctx, key: str | None, what: str | Callable[[], str],
                 max_attempts: int = 8) -> None:
        self.READS = (key, FAULTS.ESCALATE) if key else (FAULTS.ESCALATE,)
        super().__init__(name, ctx)
        self.key, self.what, self.max_attempts = key, what, max_attempts

    def update(self) -> Status:
        err = self.bb.get(self.key) if self.key else None
        stats = self.ctx.stats
        if (self.key and err is not None and err.kind in TRANSIENT
                and stats.attempts[self.key] < self.max_attempts
                and self.bb.get(FAULTS.ESCALATE) is None):
            if stats.counted.get(self.key) is not err:
                stats.counted[self.key] = err
                if stats.is_retrying(self.key, err.kind):       # the same outage, still
                    stats.retried[err.kind] += 1
                    stats.emit(self.ctx.now(), "retry_failed", kind=err.kind,
                               message=str(err), attempt=stats.attempts[self.key])
                else:
                    stats.faults[err.kind] += 1
                    stats.emit(self.ctx.now(), "fault", kind=err.kind, message=str(err))
            stats.retrying(self.key, err.kind)
            self.feedback_message = f"{err}: starting over"
            return Status.SUCCESS
        what = self.what() if callable(self.what) else self.what
        reason = f"{what}: {err}" if err is not None else what
        if self.bb.get(FAULTS.ESCALATE) is None:
            self.bb.set(FAULTS.ESCALATE, reason)
            episode = err is not None and stats.is_retrying(self.key, err.kind)
            if err is None or (stats.counted.get(self.key) is not err and not episode):
                self.ctx.stats.faults[getattr(err, "kind", "fatal")] += 1
        self.feedback_message = reason
        return Status.RUNNING
