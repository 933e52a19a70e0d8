"""The camera's link dying at the frame source (``emulators.dying_camera``), through the
camera driver (``LatchedCamera``): every death fails the grab with a typed error in a
bounded time, a hung grab's thread is abandoned and the camera opened afresh, and no
corrupt transfer is ever handed on as an image. The link coming back, grabs work again."""

from __future__ import annotations

import time

import numpy as np
import pytest

from feeder_bt.core.clock import RealClock
from feeder_bt.core.errors import CommsLost
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CameraSpec, PylonSpec
from feeder_bt.emulators.dying_camera import DyingCameraSource
from feeder_bt.hal.camera.latched import GRAB_GRACE_S, LatchedCamera, grab_timeout_s
from feeder_bt.hal.camera.sources import STREAM_TIMEOUT_S

W, H = 64, 48
BOUND_S = 1.0           # the driver's grab time-out in these tests: a good grab on a
                        # loaded 2-core machine (a thread start, the GIL) stays far under it
GENEROUS_S = 5.0        # a grab's end, bounded, on any machine


class Belt:
    """A camera that always has a frame, counting its triggers."""

    def __init__(self) -> None:
        self.triggers = 0
        self.closed = False

    def capture(self) -> np.ndarray:
        self.triggers += 1
        return np.full((H, W), 7, np.uint8)

    def close(self) -> None:
        self.closed = True


def _cell(source) -> LatchedCamera:
    return LatchedCamera(source, RealClock(), grab_timeout_s=BOUND_S, size=(W, H))


def _end(job: Job) -> tuple[Job, float]:
    t0 = time.monotonic()
    while not job.done:
        assert time.monotonic() - t0 < GENEROUS_S, "the grab never ended"
        time.sleep(0.005)
    return job, time.monotonic() - t0


def _grab(cam: LatchedCamera) -> tuple[Job, float]:
    return _end(cam.grab())


@pytest.mark.parametrize("how", ["silence", "half_open", "drip"])
def test_a_grab_that_never_comes_fails_in_the_bound_and_the_camera_is_opened_afresh(how):
    belt = Belt()
    dying = DyingCameraSource(belt, drip_s=30.0)
    cam = _cell(dying)
    try:
        assert _grab(cam)[0].ok
        dying.cut(how)
        job, took = _grab(cam)
        assert isinstance(job.error, CommsLost) and "does not respond" in str(job.error)
        assert BOUND_S * 0.9 <= took < GENEROUS_S
        assert cam.abandoned == 1
        dying.restore()
        job, _ = _grab(cam)
        assert job.ok and job.result.image.shape == (H, W)
        assert cam.reopened == 1 and cam.source is not dying      # a fresh handle
        assert dying.closed                  # the stuck handle was closed, which ends its thread
    finally:
        cam.close()
    assert belt.closed


def test_a_half_open_link_stays_dead_on_the_old_handle_after_the_restore():
    dying = DyingCameraSource(Belt())
    dying.cut("half_open")
    dying.restore()
    cam = _cell(dying)
    try:
        job, _ = _grab(cam)
        assert isinstance(job.error, CommsLost)          # the old handle: dead for good
        assert _grab(cam)[0].ok                          # a fresh one grabs
    finally:
        cam.close()


def test_a_removed_camera_fails_at_once_and_cannot_be_opened_until_it_is_back():
    dying = DyingCameraSource(Belt())
    cam = _cell(dying)
    try:
        dying.cut("refuse")
        job, took = _grab(cam)
        assert isinstance(job.error, CommsLost) and "removed" in str(job.error)
        with pytest.raises(CommsLost, match="not found"):
            dying.reopen()
    finally:
        cam.close()


@pytest.mark.parametrize(("how", "words"), [("flood", "corrupt transfer: a 64x96"),
                                            ("garbage", "incompletely grabbed")])
def test_a_corrupt_transfer_is_a_lost_link_never_an_image(how, words):
    belt = Belt()
    dying = DyingCameraSource(belt, seed=3)
    cam = _cell(dying)
    try:
        dying.cut(how)
        for _ in range(3):
            job, took = _grab(cam)
            assert isinstance(job.error, CommsLost) and words in str(job.error), job.error
            assert job.result is None              # its words say it never hung
        dying.restore()
        job, _ = _grab(cam)
        assert job.ok and int(job.result.image[0, 0]) == 7
    finally:
        cam.close()


def test_a_source_without_reopen_that_hangs_leaves_the_worker_free():
    class Hangs(Belt):
        hang = True

        def capture(self) -> np.ndarray:
            while self.hang:
                time.sleep(0.01)
            return super().capture()

    src = Hangs()
    cam = _cell(src)
    try:
        job, took = _grab(cam)
        assert isinstance(job.error, CommsLost) and took < GENEROUS_S
        job, took = _grab(cam)              # never two threads in one source: at once
        assert "still stuck" in str(job.error)
        src.hang = False                    # it returned: a fresh thread grabs
        t0 = time.monotonic()
        while not _grab(cam)[0].ok:
            assert time.monotonic() - t0 < GENEROUS_S
            time.sleep(0.01)
        assert cam.abandoned == 1 and cam.reopened == 0
    finally:
        src.hang = False
        cam.close()


def test_the_grab_bound_lies_past_the_pylon_frame_time_out():
    """The driver gives a camera its grab's time and a second; a pylon camera, which ends
    a lost frame itself, gets its frame time-out twice first (trigger-ready, frame), and a
    stream its read time-out. The simulated cell's silent camera link waits the same
    (``sim.faults``)."""
    assert grab_timeout_s(CameraSpec()) == pytest.approx(CameraSpec().grab_s + GRAB_GRACE_S)
    pylon = CameraSpec(source="pylon:", pylon=PylonSpec(frame_timeout_s=2.0))
    assert grab_timeout_s(pylon) == pytest.approx(4.0 + GRAB_GRACE_S)
    stream = CameraSpec(source="rtsp://10.0.0.9/cam")
    assert grab_timeout_s(stream) == pytest.approx(STREAM_TIMEOUT_S + GRAB_GRACE_S)


def test_shutdown_does_not_wait_for_a_grab_hung_inside_a_locked_source():
    """pylon's source holds its lock through a grab and takes it to close: with a grab
    hung inside it, closing it on the way out would hang as long as the grab."""
    import threading

    class LockedHangs(Belt):
        def __init__(self) -> None:
            super().__init__()
            self.lock = threading.Lock()
            self.release = threading.Event()

        def capture(self) -> np.ndarray:
            with self.lock:
                self.release.wait(30.0)
                return super().capture()

        def close(self) -> None:
            with self.lock:
                super().close()

    src = LockedHangs()
    cam = _cell(src)
    job, _ = _grab(cam)
    assert isinstance(job.error, CommsLost)              # abandoned, still hung inside
    closer = threading.Thread(target=cam.close, daemon=True)
    closer.start()
    closer.join(GENEROUS_S)
    hung = closer.is_alive()
    src.release.set()                                   # let the grab end, then the close
    assert not hung, "shutdown waited for the hung grab"
    t0 = time.monotonic()
    while not src.closed:                               # closed once the grab let go
        assert time.monotonic() - t0 < GENEROUS_S
        time.sleep(0.01)
