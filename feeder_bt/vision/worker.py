"""The vision worker: recipes run off the tick, on their own thread.

On a virtual clock the result counts as ready ``latency_s`` after the request, and the
clock waits for the thread if it is slower, so fast runs are reproducible.
"""

from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..clock import Clock
from ..jobs import FutureJob, Job


class VisionWorker:
    def __init__(self, locator, clock: Clock, latency_s: float) -> None:
        self.locator = locator
        self.clock = clock
        self.latency_s = latency_s
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="vision")

    def recognise(self, image: np.ndarray) -> Job:
        def run():
            t0 = time.perf_counter()
            result = self.locator.locate(image)
            result.ms = (time.perf_counter() - t0) * 1000.0
            return result

        eta = self.clock.now() + self.latency_s if self.clock.virtual else None
        return FutureJob("vision.recognise", self.pool.submit(run), self.clock, eta=eta)

    def set_golden(self, image: np.ndarray) -> None:
        self.locator.set_golden(image)

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)
