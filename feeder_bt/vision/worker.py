"""The vision worker: recipes run off the tick.

On a real clock the recipe runs on the worker's own thread as soon as it is asked for. On
a virtual clock the result counts as ready ``latency_s`` after the request and the clock
holds at that time until it is (``FutureJob`` gating), so nothing can look at the result
earlier: the recipe then runs when the clock first waits for it, in the thread that
waits, between ticks. Handing each frame to another thread cost more than the recipe on
a busy machine (a wake-up, then the two threads trading the interpreter lock), and the
result is the same function of the same image either way, so fast runs are unchanged.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np

from feeder_bt.core.clock import Clock
from feeder_bt.core.jobs import FutureJob, Job


class DeferredFuture(Future):
    """A future whose function runs in the first thread that asks for its outcome
    (``result()`` or ``exception()``); ``done()`` only looks. Cancelling it before then
    means the function never runs."""

    def __init__(self, fn: Callable[[], Any]) -> None:
        super().__init__()
        self._fn = fn
        self._claim = threading.Lock()

    def _run(self) -> None:
        if not self._claim.acquire(blocking=False):
            return                              # another thread runs it: wait for that
        if not self.set_running_or_notify_cancel():
            return                              # cancelled before anyone asked
        try:
            result = self._fn()
        except BaseException as e:              # handed to whoever asks
            self.set_exception(e)
        else:
            self.set_result(result)

    def result(self, timeout: float | None = None) -> Any:
        if not self.done():
            self._run()
        return super().result(timeout)

    def exception(self, timeout: float | None = None) -> BaseException | None:
        if not self.done():
            self._run()
        return super().exception(timeout)


class VisionWorker:
    def __init__(self, locator, clock: Clock, latency_s: float) -> None:
        self.locator = locator
        self.clock = clock
        self.latency_s = latency_s
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vision")
        self._deferred: list[DeferredFuture] = []     # virtual clock: not run yet

    def recognise(self, image: np.ndarray) -> Job:
        def run():
            t0 = time.perf_counter()
            result = self.locator.locate(image)
            result.ms = (time.perf_counter() - t0) * 1000.0
            return result

        if self.clock.virtual:                  # run when the clock waits for it (see above)
            future = DeferredFuture(run)
            self._deferred = [f for f in self._deferred if not f.done()] + [future]
            return FutureJob("vision.recognise", future, self.clock,
                             eta=self.clock.now() + self.latency_s)
        return FutureJob("vision.recognise", self.pool.submit(run), self.clock, eta=None)

    def set_golden(self, image: np.ndarray) -> None:
        """A new golden image, for frames asked about from now on: those asked about before
        are done first, with the old one (as a worker thread would have started them)."""
        for future in self._deferred:
            if not future.cancelled():
                future.exception()
        self._deferred = []
        self.locator.set_golden(image)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
