"""One fixed-rate ticker for the cell: steps the hardware (or simulated world) to the
tick's time, ticks the cell's tree, records how long the tick took.

On a virtual clock with ``fast``, ticks in which nothing can change are skipped: when two
ticks in a row leave every node's status, the queue, the statistics, and the cell's own
count of finished jobs and of branch cycles (``Cell.activity``) unchanged, the clock jumps
to the next time something is known to happen (a job's end, a belt-distance notification,
a timer), rounded up to the tick grid. The ticks that run see exactly what they would have
seen without skipping, so results are the same.
"""

from __future__ import annotations

import math
import operator
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from feeder_bt.control.cell import Cell
from feeder_bt.core.clock import EPS, SimClock

_STATUS = operator.attrgetter("status")


@dataclass
class TickStats:
    hz: float = 50.0
    durations_ms: list[float] = field(default_factory=list)
    overruns: int = 0
    ticks: int = 0
    skipped: int = 0

    def summary(self) -> dict[str, float]:
        d = np.asarray(self.durations_ms) if self.durations_ms else np.zeros(1)
        return {"hz": self.hz, "ticks": self.ticks, "skipped": self.skipped,
                "p50_ms": round(float(np.percentile(d, 50)), 4),
                "p99_ms": round(float(np.percentile(d, 99)), 4),
                "max_ms": round(float(d.max()), 4), "overruns": self.overruns}


class Ticker:
    def __init__(self, cell: Cell, fast: bool = False, skip_idle: bool = True) -> None:
        self.cell = cell
        self.clock = cell.clock
        self.fast = fast and isinstance(self.clock, SimClock)
        self.skip_idle = skip_idle and self.fast
        self.stats = TickStats()
        self.k = 0                      # tick index on the grid
        self.t0 = self.clock.now()
        self._last_sig: tuple | None = None
        self._nodes_of: object = None           # the root whose nodes _node_list holds
        self._node_list: list | None = None
        self._wall0 = time.monotonic()

    @property
    def hz(self) -> float:
        sc = self.cell.scenario
        return sc.tick_hz if sc is not None else 50.0

    def _signature(self) -> tuple:
        c = self.cell
        q = c.ctx.queue.version if c.ctx is not None else 0
        a = c.activity               # this cell's own: another cell's jobs are not news
        return (a.jobs_finished, a.loop_restarts, q, c.stats.version, c.version, c.state,
                tuple(map(_STATUS, self._nodes())))

    def _nodes(self) -> list:
        """The ticked tree's nodes, listed again only when the cell switches trees: a tree's
        shape is fixed once built, and walking it every tick cost more than the tick."""
        root = self.cell.root
        if root is not self._nodes_of or self._node_list is None:
            self._nodes_of, self._node_list = root, self.cell.nodes()
        return self._node_list

    def tick_once(self) -> None:
        hz = self.stats.hz
        now = self.clock.now()
        self.cell.hal.step(now)
        t = time.perf_counter()
        self.cell.tick()
        dt_ms = (time.perf_counter() - t) * 1000.0
        self.stats.durations_ms.append(dt_ms)
        self.stats.ticks += 1
        if dt_ms > 1000.0 / hz:
            self.stats.overruns += 1

    def _advance(self, t_end: float) -> None:
        """Move the clock to the next tick (or further, if nothing can happen before)."""
        hz = self.hz
        if hz != self.stats.hz:             # a new scenario with its own rate: new grid
            self.t0, self.k = self.clock.now(), 0
            self.stats.hz = hz
        nxt = self.k + 1
        if self.skip_idle:
            sig = self._signature()
            if sig == self._last_sig:
                wake = self.clock.next_wake()
                target = t_end if wake is None else min(wake, t_end)
                k_wake = math.ceil((target - EPS - self.t0) * hz)
                if k_wake > nxt:
                    self.stats.skipped += k_wake - nxt
                    nxt = k_wake
            self._last_sig = sig
        self.k = nxt
        t_next = self.t0 + self.k / hz
        if isinstance(self.clock, SimClock):
            if not self.fast:       # real-time view of the simulated cell: pace to the wall
                delay = (self._wall0 + (t_next - self.t0)) - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
            self.clock.advance_to(t_next)
        else:
            delay = t_next - self.clock.now()
            if delay > 0:
                time.sleep(delay)
            else:
                self.k = math.ceil((self.clock.now() - self.t0) * hz)

    def run(self, until: float | None = None, stop: Callable[[], bool] | None = None,
            every: Callable[[], None] | None = None) -> None:
        """Tick until clock time ``until`` or ``stop()`` is true; ``every()`` after each tick."""
        with self.cell.activity.counting():     # what ends meanwhile is this cell's news
            self._run(math.inf if until is None else until, stop, every)

    def _run(self, t_end: float, stop: Callable[[], bool] | None,
             every: Callable[[], None] | None) -> None:
        while self.clock.now() < t_end - 1e-12:
            self.tick_once()
            if every is not None:
                every()
            if stop is not None and stop():
                return
            self._advance(t_end)
