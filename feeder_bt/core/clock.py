"""Time for the control path.

Nothing in the control path calls ``time.time()`` or ``time.sleep()``: it asks a ``Clock``.
``SimClock`` is virtual time; it also keeps the times at which something is known to happen
(job completions, belt-distance notifications, timers) so that a fast run can jump over
ticks in which nothing can change, and the results do not depend on the machine's speed.
"""

from __future__ import annotations

import heapq
import time
from concurrent.futures import CancelledError, Future

EPS = 1e-9      # times this close count as the same instant (float sums of tick periods)


class Clock:
    """Interface: ``now()`` in seconds, monotonic; ``wake_at(t)`` hints a future event."""

    def now(self) -> float:
        raise NotImplementedError

    def wake_at(self, t: float) -> None:
        """Tell the ticker something may change at time ``t`` (ignored by real clocks)."""

    def gate(self, eta: float, future: Future) -> None:
        """Hold virtual time at ``eta`` until ``future`` is done (ignored by real clocks)."""

    @property
    def virtual(self) -> bool:
        return False


class RealClock(Clock):
    def __init__(self) -> None:
        self._t0 = time.monotonic()

    def now(self) -> float:
        return time.monotonic() - self._t0


class SimClock(Clock):
    """Virtual time, advanced only by the ticker (or a test)."""

    def __init__(self, start: float = 0.0) -> None:
        self._now = float(start)
        self._wakes: list[float] = []
        self._gates: list[tuple[float, int, Future]] = []
        self._seq = 0

    @property
    def virtual(self) -> bool:
        return True

    def now(self) -> float:
        return self._now

    def wake_at(self, t: float) -> None:
        if t > self._now:
            heapq.heappush(self._wakes, t)

    def gate(self, eta: float, future: Future) -> None:
        self._seq += 1
        heapq.heappush(self._gates, (eta, self._seq, future))

    def next_wake(self) -> float | None:
        """Earliest hinted time strictly after now, or None."""
        while self._wakes and self._wakes[0] <= self._now + EPS:
            heapq.heappop(self._wakes)
        return self._wakes[0] if self._wakes else None

    def advance_to(self, t: float) -> None:
        """Move virtual time forward, first waiting for worker results due by then."""
        if t < self._now:
            raise ValueError(f"SimClock cannot go back from {self._now} to {t}")
        while self._gates and self._gates[0][0] <= t + EPS:
            _, _, fut = heapq.heappop(self._gates)
            try:
                fut.exception()  # waits; the job reads the result itself
            except CancelledError:
                pass
        self._now = t

    def advance(self, dt: float) -> None:
        self.advance_to(self._now + dt)


#: a round trip longer than this had a reconnect or a queue in it: when in it the device
#: sampled is unknown, and its end is taken
SLOW_ROUND_TRIP_S = 0.2


def sampled_at(sent: float, received: float) -> float:
    """When a device most likely sampled what a reply carries: the middle of the round
    trip. Stamped at its end, a count is as late as half the round trip plus the reader's
    wake-up, and carried forward by a belt's speed that lateness is millimetres: the
    encoder check saw 3 mm of drift on a loaded machine from it."""
    rtt = received - sent
    return received - rtt / 2.0 if 0.0 <= rtt <= SLOW_ROUND_TRIP_S else received
