"""Jobs: the only way a leaf asks for something that takes time.

A leaf starts a job in ``initialise()``, polls it in ``update()`` and cancels it in
``terminate()``. A job never blocks its caller. Errors surface as typed ``HalError``s in
``job.error`` when the job ends in ``FAILED``.
"""

from __future__ import annotations

import contextlib
import enum
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from contextvars import ContextVar
from typing import Any

from feeder_bt.core.clock import EPS, Clock
from feeder_bt.core.errors import HalError, JobCancelled


class JobState(enum.Enum):
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"


class Activity:
    """One cell's news, counted so that its ticker does not skip a tick that has some: jobs
    that ended and branch cycles that began again (``trees.build.Loop``).

    A job does not know its cell, so the cell's ticker makes its ``Activity`` the one
    ``counting()`` while it steps the cell: every job that ends meanwhile, in that thread,
    is the cell's. Two cells in one process, or in two threads, count apart."""

    def __init__(self) -> None:
        self.jobs_finished = 0
        self.loop_restarts = 0

    @contextlib.contextmanager
    def counting(self) -> Iterator[Activity]:
        """Jobs that end inside the block are this activity's."""
        token = _COUNTING.set(self)
        try:
            yield self
        finally:
            _COUNTING.reset(token)

    @staticmethod
    def current() -> Activity | None:
        """The activity counting now in this thread (None: nobody's)."""
        return _COUNTING.get()


_COUNTING: ContextVar[Activity | None] = ContextVar("feeder_activity", default=None)


class Job:
    """Handle to an operation in progress. Subclasses decide how it finishes."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.state = JobState.RUNNING
        self.result: Any = None
        self.error: HalError | None = None
        self._callbacks: list[Callable[[Job], None]] = []

    # -- for the owner of the job -------------------------------------------------------
    def poll(self) -> JobState:
        return self.state

    @property
    def done(self) -> bool:
        return self.poll() is not JobState.RUNNING

    @property
    def ok(self) -> bool:
        return self.poll() is JobState.SUCCEEDED

    def cancel(self) -> None:
        if self.state is JobState.RUNNING:
            self._on_cancel()
            self._finish(JobState.CANCELLED, error=JobCancelled(f"{self.name} cancelled"))

    def add_done_callback(self, fn: Callable[[Job], None]) -> None:
        if self.state is JobState.RUNNING:
            self._callbacks.append(fn)
        else:
            fn(self)

    # -- for the implementation --------------------------------------------------------
    def _on_cancel(self) -> None:
        """Hook: stop the underlying operation."""

    def succeed(self, result: Any = None) -> None:
        self._finish(JobState.SUCCEEDED, result=result)

    def fail(self, error: HalError) -> None:
        self._finish(JobState.FAILED, error=error)

    def _finish(self, state: JobState, result: Any = None, error: HalError | None = None) -> None:
        if self.state is not JobState.RUNNING:
            return
        self.state, self.result, self.error = state, result, error
        activity = _COUNTING.get()
        if activity is not None:            # lets the cell's ticker notice it
            activity.jobs_finished += 1
        callbacks, self._callbacks = self._callbacks, []
        for fn in callbacks:
            fn(self)

    def __repr__(self) -> str:
        return f"<Job {self.name} {self.state.value}>"


class DoneJob(Job):
    """A job that finished at once (cheap operations keep the same interface)."""

    def __init__(self, name: str, result: Any = None, error: HalError | None = None) -> None:
        super().__init__(name)
        if error is None:
            self.succeed(result)
        else:
            self.fail(error)


class FutureJob(Job):
    """A job carried out by a worker thread.

    On a virtual clock, ``eta`` is when the job counts as finished in virtual time; the
    clock will not pass ``eta`` before the worker is done, so a run's results do not
    depend on how fast the machine is.
    """

    def __init__(self, name: str, future: Future, clock: Clock, eta: float | None = None) -> None:
        super().__init__(name)
        self._future = future
        self._clock = clock
        self.eta = eta
        if clock.virtual and eta is not None:
            clock.wake_at(eta)
            clock.gate(eta, future)

    def poll(self) -> JobState:
        if self.state is JobState.RUNNING and self._future.done():
            if self.eta is None or not self._clock.virtual or self._clock.now() >= self.eta - EPS:
                exc = self._future.exception()
                if exc is None:
                    self.succeed(self._future.result())
                elif isinstance(exc, HalError):
                    self.fail(exc)
                else:
                    self.fail(HalError(f"{self.name}: {type(exc).__name__}: {exc}"))
        return self.state

    def _on_cancel(self) -> None:
        self._future.cancel()
