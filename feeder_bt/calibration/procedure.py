"""What the calibration procedures share: their error type and how they wait for a job.

A procedure drives the cell through the HAL interfaces only, so the same code runs on the
simulated cell now and on a real cell once its drivers exist. It waits for each ``Job``
through a ``Waiter`` that the caller supplies: on the simulated cell that advances virtual
time (``sim_waiter``); on a real cell it will poll on the real clock.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import FeederError
from feeder_bt.core.jobs import Job

Waiter = Callable[[Job], Any]


class CalibrationError(FeederError):
    """A calibration cannot be computed from what was measured (too few points, degenerate
    poses, no target in the image); the message says what to do about it."""

    exit_code = 2


def sim_waiter(hal: Any, clock: SimClock, timeout_s: float = 600.0) -> Waiter:
    """A ``Waiter`` for the simulated cell: advance virtual time until the job ends.

    Returns the job's result; raises its typed error if it failed, or ``CalibrationError``
    if nothing is scheduled that could ever finish it.
    """

    def wait(job: Job) -> Any:
        deadline = clock.now() + timeout_s
        while not job.done:
            t = clock.next_wake()
            if t is None or t > deadline:
                raise CalibrationError(f"{job.name} did not finish within {timeout_s:g} s "
                                       "of simulated time")
            clock.advance_to(t)
            hal.step(t)
        if job.error is not None:
            raise job.error
        return job.result

    return wait


def rms_max(residuals: Any) -> tuple[float, float]:
    """RMS and maximum of the lengths of ``(N, 2)`` residual vectors (mm)."""
    d = np.linalg.norm(np.asarray(residuals, dtype=float).reshape(-1, 2), axis=1)
    if d.size == 0:
        return 0.0, 0.0
    return float(np.sqrt(np.mean(d * d))), float(d.max())
