"""The link under the Galil driver: one open connection with its reader thread, the timer
thread of multi-step operations, and the small future helpers they share."""

from __future__ import annotations

import heapq
import itertools
import logging
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, InvalidStateError
from typing import Any

import serial

from feeder_bt.hal.galil.protocol import ProtocolError, Reply, ReplySplitter

log = logging.getLogger("feeder_bt.hal.galil.driver")

DEAD = object()            # put in the reply queue when the link dies


class Connection:
    """One open link: the serial object, its reader thread and its reply queue."""

    def __init__(self, ser: serial.SerialBase, on_line: Callable[[str], None], name: str) -> None:
        self.ser = ser
        self.on_line = on_line
        self.splitter = ReplySplitter()
        self.replies: queue.Queue = queue.Queue()
        self.alive = True
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._read_loop, name=f"galil-reader-{name}",
                                       daemon=True)
        self.thread.start()

    def _read_loop(self) -> None:
        while self.alive:
            try:
                data = self.ser.read(1)
            except Exception as e:               # noqa: BLE001 - any failure: the link is gone
                self._die(e)
                return
            if not data:
                continue
            try:
                items = self.splitter.feed(data)
            except ProtocolError as e:
                self._die(e)
                return
            for item in items:
                if isinstance(item, Reply):
                    self.replies.put(item)
                else:
                    try:
                        self.on_line(item.text)
                    except Exception:            # noqa: BLE001 - a subscriber must not kill us
                        log.exception("Galil event handler failed on %r", item.text)

    def _die(self, e: BaseException) -> None:
        if self.alive:
            self.error = e
        self.alive = False
        self.replies.put(DEAD)

    def close(self) -> None:
        self.alive = False
        self.replies.put(DEAD)
        try:
            self.ser.close()
        except Exception:                        # noqa: BLE001 - closing a broken link
            pass
        if self.thread is not threading.current_thread():
            self.thread.join(1.0)


class Scheduler:
    """Calls functions after a delay on one timer thread (continuations of operations)."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._cv = threading.Condition()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="galil-scheduler", daemon=True)
        self._thread.start()

    def call_later(self, delay: float, fn: Callable[[], None]) -> None:
        with self._cv:
            heapq.heappush(self._heap, (time.monotonic() + max(0.0, delay), next(self._seq), fn))
            self._cv.notify()

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._closed and (not self._heap
                                            or self._heap[0][0] > time.monotonic()):
                    timeout = self._heap[0][0] - time.monotonic() if self._heap else None
                    self._cv.wait(timeout)
                if self._closed:
                    return
                _, _, fn = heapq.heappop(self._heap)
            try:
                fn()
            except Exception:                    # noqa: BLE001
                log.exception("Galil scheduled call failed")

    def close(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify()
        self._thread.join(1.0)


# ------------------------------------------------------------------------ futures


def retrieve(f: Future) -> None:
    """Mark a fire-and-forget future's exception as seen."""
    if not f.cancelled():
        f.exception()


def done(value: Any) -> Future:
    f: Future = Future()
    f.set_result(value)
    return f


def failed(e: BaseException) -> Future:
    f: Future = Future()
    f.set_exception(e)
    return f


def set_result(f: Future, value: Any) -> None:
    try:
        f.set_result(value)
    except InvalidStateError:
        pass


def set_exception(f: Future, e: BaseException) -> None:
    try:
        f.set_exception(e)
    except InvalidStateError:
        pass
