"""A GenICam camera through pypylon, against Basler's own camera emulator (``PYLON_CAMEMU``):
software and line triggers, and every grab paired with its own trigger — a lost frame, an
extra trigger, a camera closed mid-run and a wrong pixel format are each caught with one
line, counted, and never paired with another trigger's image."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from feeder_bt.core.errors import ConfigError, GrabFailed
from feeder_bt.core.model import PylonSpec

pytest.importorskip("pypylon", reason="pypylon is not installed (pip install -e '.[pylon]')")

from feeder_bt.emulators.pylon_camera import ImageFiles  # noqa: E402
from feeder_bt.hal.camera.pylon import PylonSource, list_cameras  # noqa: E402

W, H = 320, 240


@pytest.fixture(autouse=True)
def camemu(monkeypatch):
    """Two emulated cameras; pylon reads PYLON_CAMEMU at each enumeration."""
    monkeypatch.setenv("PYLON_CAMEMU", "2")


class Scene:
    """Frames that say which trigger they are: trigger k draws a bar at column 10 k."""

    def __init__(self) -> None:
        self.files = ImageFiles((W, H))
        self.k = 0

    def before_trigger(self) -> None:
        self.k += 1
        img = np.full((H, W), 20, np.uint8)
        c = (10 * self.k) % (W - 8)
        img[:, c:c + 4] = 250
        self.files.write(img)

    @staticmethod
    def trigger_of(img: np.ndarray) -> int:
        cols = np.flatnonzero(img.mean(axis=0) > 200)
        assert cols.size, "no bar in the frame"
        return int(cols[0]) // 10


@pytest.fixture
def scene():
    s = Scene()
    yield s
    s.files.remove()


def open_cam(scene: Scene, spec: str = "pylon:", line_pulse=None, configure=None,
             **settings) -> PylonSource:
    def setup(cam) -> None:
        scene.files.configure(cam)
        if configure is not None:
            configure(cam)
    settings.setdefault("frame_timeout_s", 10.0)      # generous: a loaded machine
    return PylonSource(spec, PylonSpec(**settings), 2.0, (W, H),
                       before_trigger=scene.before_trigger, line_pulse=line_pulse,
                       configure=setup)


def test_the_emulator_enumerates_the_cameras_the_environment_asks_for():
    cams = list_cameras()
    assert len(cams) == 2 and all(c["class"] == "BaslerCamEmu" for c in cams)


def test_software_trigger_pairs_every_frame_with_its_own_trigger(scene):
    src = open_cam(scene, spec="pylon:0815-0001")
    try:
        assert src.serial == "0815-0001"
        for _ in range(6):
            img = src.capture()
            assert img.shape == (H, W) and img.dtype == np.uint8
            assert Scene.trigger_of(img) == scene.k
        assert src.counts() == {"frames": 6, "lost_frames": 0, "extra_triggers": 0}
        assert src.cam.ExposureTime.Value == pytest.approx(2000.0)
    finally:
        src.close()


def test_line_trigger_waits_for_the_line_and_fires_on_it(scene):
    """No pulse on Line1, no frame (one line, counted); with the pulse, the frame."""
    src = open_cam(scene, trigger="Line1", frame_timeout_s=0.3)
    try:
        assert src.cam.TriggerSource.Value == "Line1"
        with pytest.raises(GrabFailed, match=r"trigger with no frame in 0.3 s \(Line1\)"):
            src.capture()
        assert src.counts()["lost_frames"] == 1
        # the emulator has no electrical input: the bridge's TriggerSoftware is the wire;
        # from here a frame is due, so the wait is generous (a loaded machine)
        src.line_pulse = src.cam.ExecuteSoftwareTrigger
        src.settings.frame_timeout_s = 10.0
        for _ in range(3):
            assert Scene.trigger_of(src.capture()) == scene.k
    finally:
        src.close()


def test_a_lost_frame_drops_the_pair_and_the_next_one_is_paired_right(scene):
    src = open_cam(scene)
    try:
        src.capture()
        src.cam.ForceFailedBufferCount.Value = 1   # CamEmu: the next buffer fails
        src.cam.ForceFailedBuffer.Execute()
        with pytest.raises(GrabFailed, match=r"frame 1 lost: The buffer was incompletely"):
            src.capture()
        img = src.capture()
        assert Scene.trigger_of(img) == scene.k == 3
        assert src.counts() == {"frames": 2, "lost_frames": 1, "extra_triggers": 0}
    finally:
        src.close()


def test_an_extra_trigger_is_drained_counted_and_never_paired(scene):
    src = open_cam(scene)
    try:
        first = src.capture()
        assert Scene.trigger_of(first) == 1
        src.cam.WaitForFrameTriggerReady(5000, src.pylon.TimeoutHandling_ThrowException)
        src.cam.ExecuteSoftwareTrigger()           # a pulse nobody asked for
        img = src.capture()
        assert Scene.trigger_of(img) == scene.k == 2
        assert src.counts()["extra_triggers"] == 1
        assert src.last_id == 2                    # the camera's counter: 0, 1 (extra), 2
    finally:
        src.close()


def test_a_gap_in_the_frame_counter_drops_the_pair(scene):
    """A frame the transport lost without a trace: the counter jumps; never paired."""
    src = open_cam(scene)
    try:
        src.capture()
        src.last_id -= 1                   # as if a frame between went missing
        with pytest.raises(GrabFailed, match="frame counter 1, expected 0: pair dropped"):
            src.capture()
        assert Scene.trigger_of(src.capture()) == scene.k
    finally:
        src.close()


def test_a_camera_closed_mid_run_fails_one_grab_with_one_line_then_recovers(scene):
    src = open_cam(scene)
    try:
        src.capture()
        closer = threading.Thread(target=src.cam.Close)     # someone else closes it
        closer.start()
        closer.join(30)
        with pytest.raises(GrabFailed) as e:
            src.capture()
        assert "\n" not in str(e.value) and "the camera is gone" in str(e.value)
        assert "reopened" in str(e.value)
        assert Scene.trigger_of(src.capture()) == scene.k
        assert src.reopened == 1 and src.counts()["lost_frames"] == 1
    finally:
        src.close()


def test_a_camera_that_stays_gone_fails_every_grab_with_one_line(scene, monkeypatch):
    src = open_cam(scene)
    try:
        src.cam.Close()
        monkeypatch.setenv("PYLON_CAMEMU", "0")      # unplugged: not enumerated any more
        for _ in range(2):
            with pytest.raises(GrabFailed, match="the camera is gone.*no such pylon camera"):
                src.capture()
    finally:
        src.close()


def test_a_frame_in_another_pixel_format_is_refused(scene):
    calls = []

    def mono16(cam) -> None:         # the camera set otherwise behind the cell's back, once
        calls.append(1)
        if len(calls) > 1:
            return
        cam.ImageFileMode.Value = "Off"
        cam.TestImageSelector.Value = "Testimage1"
        cam.PixelFormat.Value = "Mono16"
    src = open_cam(scene, configure=mono16)
    try:
        with pytest.raises(GrabFailed, match="pixel format Mono16, the cell expects Mono8: "
                                             "settings sent again"):
            src.capture()
        assert src.cam.PixelFormat.Value == "Mono8"
        assert Scene.trigger_of(src.capture()) == scene.k       # and it grabs again
    finally:
        src.close()


def test_setup_errors_are_one_line_config_errors(scene):
    with pytest.raises(ConfigError, match=r"pylon:NOPE: no such pylon camera \(cameras found: "
                                          r"0815-0000, 0815-0001"):
        open_cam(scene, spec="pylon:NOPE")
    with pytest.raises(ConfigError, match=r"camera.pylon: pylon:: GevSCPSPacketSize 99999: "
                                          r"Value = 99999 must be equal or smaller than"):
        open_cam(scene, packet_size=99999)


def test_gige_transport_settings_reach_the_camera(scene):
    src = open_cam(scene, packet_size=1500, inter_packet_delay=100, gain_db=6.0)
    try:
        assert src.cam.GevSCPSPacketSize.Value == 1500
        assert src.cam.GevSCPD.Value == 100
        assert src.cam.Gain.Value == pytest.approx(6.0, abs=0.01)
    finally:
        src.close()


def test_a_line_triggers_edge_and_delay_reach_the_camera(scene):
    """The emulator has both ExposureTime and ExposureTimeAbs: the SFNC 2 name is taken."""
    src = open_cam(scene, trigger="Line1", trigger_activation="FallingEdge",
                   trigger_delay_us=100.0)
    try:
        assert src.cam.TriggerActivation.Value == "FallingEdge"
        assert src.cam.TriggerDelay.Value == pytest.approx(100.0)
        assert src.feature("ExposureTime") == "ExposureTime"
        assert src.feature("Gain") == "Gain"
        assert src.exposure_us() == pytest.approx(2000.0)
    finally:
        src.close()
    # the emulator has no line debouncer under either name: one line naming both
    with pytest.raises(ConfigError, match="the camera has no writable LineDebouncerTime "
                                          "nor LineDebouncerTimeAbs"):
        open_cam(scene, trigger="Line1", line_debouncer_us=10.0)
