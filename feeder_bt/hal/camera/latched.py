"""A camera whose trigger also latches the conveyor encoder (thesis section 2.3).

The trigger line is wired both to the camera and to the conveyor controller's latch
input, so the image and the belt position are taken at the same instant. A grab arms the
latch, triggers the source, then reads the latched count — all on the camera's own
worker, so the tick never waits.

The source's own calls (``prepare``, ``capture``, ``reopen``) run on a capture thread of
their own, bounded by ``grab_timeout_s``: a grab that never returns (a camera link gone
silent inside the vendor SDK, a frame dripping in) fails with ``CommsLost`` in that time,
the stuck thread is abandoned (a daemon: it ends if its call ever returns) and the next
grab opens the camera afresh (``source.reopen()``) on a new one. A frame that is not a
grey image of the camera's size (a corrupt transfer) is never handed to the recipe.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, Protocol

import numpy as np

from feeder_bt.core.clock import Clock
from feeder_bt.core.errors import CommsLost, FeederError, GrabFailed, HalError
from feeder_bt.core.jobs import DoneJob, FutureJob, Job
from feeder_bt.core.model import CameraSpec
from feeder_bt.hal.camera.sources import STREAM_TIMEOUT_S, FrameSource
from feeder_bt.hal.interfaces import Frame

#: past the grab's own time, how long a camera may take to answer before the driver gives
#: its link up; the simulated cell waits the same on a silent camera link
GRAB_GRACE_S = 1.0


def grab_timeout_s(camera: CameraSpec) -> float:
    """How long one grab may run before the camera counts as not responding: its own time
    and ``GRAB_GRACE_S``. A pylon camera ends a lost frame itself in
    ``pylon.frame_timeout_s``, once waiting to be ready for the trigger and once for the
    frame: the driver's bound lies past both, so a lost frame stays a lost frame. A stream
    (a URL) ends a read itself in ``STREAM_TIMEOUT_S``: the bound lies past that too."""
    bound = camera.grab_s + GRAB_GRACE_S
    if camera.source.startswith("pylon:"):
        bound = max(bound, 2 * camera.pylon.frame_timeout_s + GRAB_GRACE_S)
    elif "://" in camera.source:
        bound = max(bound, STREAM_TIMEOUT_S + GRAB_GRACE_S)
    return bound


class LatchSource(Protocol):
    """The conveyor controller's position latch (a Galil axis: ``AL`` / ``RL``)."""

    def arm_latch(self) -> Job: ...

    def read_latch(self) -> Job: ...


def wait_job(job: Job, timeout_s: float, what: str) -> object:
    """Wait for a job from a worker thread (never from the tick); its result or its error."""
    deadline = time.monotonic() + timeout_s
    while not job.done:
        if time.monotonic() > deadline:
            job.cancel()
            raise GrabFailed(f"{what}: no answer in {timeout_s:g} s")
        time.sleep(0.001)
    if not job.ok:
        raise job.error or HalError(f"{what} failed")
    return job.result


class _CaptureThread:
    """One daemon thread running a source's calls in turn. A daemon, not a pool's worker:
    an abandoned one stuck in the SDK must not hold the process at exit."""

    def __init__(self) -> None:
        self._calls: queue.SimpleQueue = queue.SimpleQueue()
        threading.Thread(target=self._run, daemon=True, name="camera-capture").start()

    def call(self, fn: Callable[[], Any], timeout_s: float, done: Future) -> Any:
        """``fn()``'s result or error (also set on ``done``); ``FutureTimeout`` when it has
        not returned in time."""
        self._calls.put((fn, done))
        return done.result(timeout=timeout_s)

    def stop(self) -> None:
        """End the thread once the call it is in (if any) returns."""
        self._calls.put(None)

    def _run(self) -> None:
        while True:
            item = self._calls.get()
            if item is None:
                return
            fn, done = item
            try:
                done.set_result(fn())
            except BaseException as e:          # handed to the waiting grab
                done.set_exception(e)


class LatchedCamera:
    def __init__(self, source: FrameSource, clock: Clock, latch: LatchSource | None = None,
                 timeout_s: float = 2.0, grab_timeout_s: float = 2.0,
                 size: tuple[int, int] | None = None) -> None:
        self.source, self.clock, self.latch = source, clock, latch
        self.timeout_s = timeout_s
        self.grab_timeout_s = grab_timeout_s
        self.size = size                 # (width, height) every frame must have; None: any
        self.worker = ThreadPoolExecutor(max_workers=1, thread_name_prefix="camera")
        self.frames = 0
        self.exposure_ms: float | None = None
        self.abandoned = 0               # capture threads given up, stuck in a grab
        self.reopened = 0
        self._capture: _CaptureThread | None = None
        self._stuck: Future | None = None   # an abandoned call, on a source kept in use
        self._stale = False              # the source hung: open it afresh before a grab

    def _call(self, fn: Callable[[], Any], what: str) -> Any:
        """A call of the source on the capture thread, bounded by ``grab_timeout_s``."""
        if self._stuck is not None and not self._stuck.done():
            # a source that cannot be opened afresh is never called from two threads
            raise CommsLost(f"camera: {what}: still stuck in a grab abandoned "
                            f"{self.grab_timeout_s:g} s or more ago (link lost)")
        self._stuck = None
        if self._capture is None:
            self._capture = _CaptureThread()
        done: Future = Future()
        try:
            return self._capture.call(fn, self.grab_timeout_s, done)
        except FutureTimeout:
            self._capture.stop()
            self._capture = None
            self.abandoned += 1
            self._stale = hasattr(self.source, "reopen")
            if not self._stale:
                self._stuck = done
            again = " and the camera opened afresh" if self._stale else ""
            raise CommsLost(f"camera: {what}: no answer in {self.grab_timeout_s:g} s, the "
                            f"camera does not respond (link lost); abandoned{again}") from None

    def _reopen(self) -> None:
        """A fresh handle on the camera, in place of one whose grab hung."""
        try:
            self.source = self._call(self.source.reopen, "opening it again")  # type: ignore[attr-defined]
        except (FeederError, OSError) as e:
            if isinstance(e, CommsLost):
                raise
            raise CommsLost(f"camera: opening it again: {e} (link lost)") from None
        self._stale = False
        self.reopened += 1

    def _check(self, image: Any) -> np.ndarray:
        """What came is an image of the camera's: a grey uint8 frame of its size. Anything
        else is a corrupt transfer; like a reply that does not parse on the other links,
        the driver drops the handle (opened afresh at the next grab)."""
        ok = isinstance(image, np.ndarray) and image.ndim == 2 and image.dtype == np.uint8 \
            and image.size > 0
        if ok and self.size is not None:
            ok = image.shape == (self.size[1], self.size[0])
        if ok:
            return image
        self._stale = hasattr(self.source, "reopen")
        shape = "x".join(str(n) for n in reversed(getattr(image, "shape", ())))
        want = f"{self.size[0]}x{self.size[1]}" if self.size is not None else "grey uint8"
        raise CommsLost(f"camera: corrupt transfer: a {shape or type(image).__name__} "
                        f"{getattr(image, 'dtype', '')} frame, expected {want} (link lost)")

    def _grab(self, index: int) -> Frame:
        if self._stale:
            self._reopen()
        prepare = getattr(self.source, "prepare", None)
        if prepare is not None:       # a camera counting its frames drops strays before AL
            self._call(prepare, "draining stray frames")
        if self.latch is not None:
            wait_job(self.latch.arm_latch(), self.timeout_s, "arming the encoder latch")
        t = self.clock.now()
        image = self._check(self._call(self.source.capture, "grab"))
        latch = 0
        if self.latch is not None:
            latch = int(wait_job(self.latch.read_latch(), self.timeout_s,   # type: ignore[arg-type]
                                 "reading the encoder latch"))
        return Frame(image=image, latch=latch, t=t, index=index)

    def grab(self) -> Job:
        self.frames += 1
        return FutureJob("camera.grab", self.worker.submit(self._grab, self.frames), self.clock)

    def set_exposure(self, ms: float) -> Job:
        self.exposure_ms = ms       # sources without an exposure control ignore it
        return DoneJob("camera.set_exposure")

    def close(self) -> None:
        self.worker.shutdown(wait=True, cancel_futures=True)
        if self._capture is not None:
            self._capture.stop()
        if self._stuck is not None and not self._stuck.done():
            # a grab still hangs inside the source, which may hold its own lock (pylon's
            # does): closing it here could hang as long, so it is closed on a thread of its
            # own that shutdown does not wait for
            threading.Thread(target=self._close_source, name="camera-close",
                             daemon=True).start()
            return
        self.source.close()

    def _close_source(self) -> None:
        try:
            self.source.close()
        except Exception:             # noqa: BLE001 - shutting down: nothing to tell
            pass
