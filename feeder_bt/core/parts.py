"""Located parts and the multi-part queue (thesis 5.3.2 and 8.2.1.5).

The queue keeps one FIFO per part type. Leaves use it without blocking (``get`` returns
``None`` when empty); threads outside the tick (a remote client, a test) may block with a
timeout, and ``wake_all`` releases every waiter so that the cell always reaches STOPPED.
"""

from __future__ import annotations

import heapq
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from feeder_bt.core.encoder import diff


@dataclass
class Part:
    """A part as the locator saw it: pose in the belt frame at the moment of the latch."""

    id: int
    type: str
    x_mm: float
    y_mm: float
    angle_deg: float
    latch: int                 # robot controller's encoder count at the latch
    located_at: float          # clock time of the grab
    pose: str = ""
    pickable: bool = True
    frame: int = 0
    features: dict[str, float] = field(default_factory=dict)
    # where to grip it (``PartSpec.pick``): offset of the grip point from (x_mm, y_mm)
    grip_dx_mm: float = 0.0
    grip_dy_mm: float = 0.0
    grip_deg: float = 0.0      # the gripper's turn from angle_deg at the grip

    def x_at(self, count: int, bits: int, counts_per_mm: float) -> float:
        """Its x when the robot's belt encoder reads ``count``: it moved with the belt."""
        return self.x_mm + diff(count, self.latch, bits) / counts_per_mm


class PartsQueue:
    """One FIFO per part type behind a single lock (thesis 8.2.1.5).

    ``get(type)`` lets an assembly sequence ask for a washer without pulling nuts out of
    the way; ``get()`` takes the oldest head over all FIFOs, so single-type feeding behaves
    like the thesis's single pipe. ``version`` changes on every mutation so a ticker can
    notice activity without copying the queue.
    """

    def __init__(self, types: Iterable[str] | None = None) -> None:
        self._cond = threading.Condition()
        self._fifos: dict[str, deque[Part]] = {}
        for t in types or ():
            self._fifos.setdefault(t, deque())
        self._version = 0
        self._wake_gen = 0

    # ------------------------------------------------------------------ inspection

    @property
    def version(self) -> int:
        """Incremented on every change, so equal versions mean nothing happened."""
        with self._cond:
            return self._version

    @property
    def types(self) -> tuple[str, ...]:
        """Types in order of declaration or first appearance; breaks ties in ``get()``."""
        with self._cond:
            return tuple(self._fifos)

    def __len__(self) -> int:
        with self._cond:
            return sum(len(f) for f in self._fifos.values())

    def count(self, type: str) -> int:
        """Parts waiting of one type (0 for a type never seen)."""
        with self._cond:
            fifo = self._fifos.get(type)
            return len(fifo) if fifo is not None else 0

    def peek_all(self) -> list[Part]:
        """Snapshot in the order successive ``get()`` calls would return the parts."""
        with self._cond:
            return self._merged()

    # ------------------------------------------------------------------ mutation

    def put(self, part: Part) -> None:
        """Append to the back of the part's own FIFO and wake waiters."""
        with self._cond:
            self._fifos.setdefault(part.type, deque()).append(part)
            self._changed()

    def put_front(self, part: Part) -> None:
        """Put a part back at the front of its FIFO, e.g. after an aborted pick."""
        with self._cond:
            self._fifos.setdefault(part.type, deque()).appendleft(part)
            self._changed()

    def get(self, type: str | None = None, block: bool = False,
            timeout: float | None = None) -> Part | None:
        """Remove and return the next part (of ``type``, or the oldest head if None).

        Leaves in the tick must never block, so the default returns None at once when
        nothing fits. With ``block=True`` the caller waits up to ``timeout`` (forever if
        None) and gets None on timeout or when ``wake_all`` is called, so a stopping
        retriever can never hang the cell.
        """
        with self._cond:
            part = self._pop(type)
            if part is not None or not block:
                return part
            gen = self._wake_gen
            deadline = None if timeout is None else time.monotonic() + timeout
            while True:
                if deadline is None:
                    self._cond.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return None
                    self._cond.wait(remaining)
                if self._wake_gen != gen:
                    return None
                part = self._pop(type)
                if part is not None:
                    return part

    def remove(self, part_id: int) -> bool:
        """Drop one part by id (e.g. picked through another path); False if absent."""
        with self._cond:
            for fifo in self._fifos.values():
                for i, part in enumerate(fifo):
                    if part.id == part_id:
                        del fifo[i]
                        self._changed()
                        return True
            return False

    def take(self, pred: Callable[[Part], bool]) -> list[Part]:
        """Remove every part matching ``pred`` (e.g. gone past ``too_far``), oldest first."""
        with self._cond:
            taken = [p for p in self._merged() if pred(p)]
            if not taken:
                return []
            ids = {id(p) for p in taken}
            for t, fifo in self._fifos.items():
                self._fifos[t] = deque(p for p in fifo if id(p) not in ids)
            self._changed()
            return taken

    def flush(self) -> list[Part]:
        """Empty the queue and hand back what was in it, so no part goes unaccounted."""
        with self._cond:
            parts = self._merged()
            if parts:
                for fifo in self._fifos.values():
                    fifo.clear()
                self._changed()
            return parts

    def wake_all(self) -> None:
        """Make every currently blocked ``get`` return None (thesis 5.3.2: reach STOPPED)."""
        with self._cond:
            self._wake_gen += 1
            self._cond.notify_all()

    # ------------------------------------------------------------------ internals

    def _changed(self) -> None:
        self._version += 1
        self._cond.notify_all()

    def _pop(self, type: str | None) -> Part | None:
        if type is not None:
            fifo = self._fifos.get(type)
            if not fifo:
                return None
        else:
            heads = [f for f in self._fifos.values() if f]
            if not heads:
                return None
            fifo = min(heads, key=lambda f: _age_key(f[0]))   # first minimal: type order
        part = fifo.popleft()
        self._changed()
        return part

    def _merged(self) -> list[Part]:
        return list(heapq.merge(*self._fifos.values(), key=_age_key))


def _age_key(part: Part) -> tuple[float, int]:
    return (part.located_at, part.id)
