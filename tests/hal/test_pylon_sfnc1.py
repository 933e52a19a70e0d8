"""What Basler's camera emulator cannot show, on a fake node map (tests/support/fake_pylon):
an older GigE camera with SFNC 1 names only (``ExposureTimeAbs``, ``GainRaw``,
``TriggerDelayAbs``, ``LineDebouncerTimeAbs``) is set as fully as a current one; the GigE
block id wraps from 65535 to 1 without a false drop, and a camera whose block id is 0 (no
counter) has every frame paired by order; stray frames are drained on a camera that cannot
say when it is ready for a trigger. None of this needs pypylon."""

from __future__ import annotations

import itertools

import pytest

from feeder_bt.core.errors import ConfigError, GrabFailed
from feeder_bt.core.model import PylonSpec
from feeder_bt.hal.camera.pylon import (
    BLOCK_ID_INVALID,
    PylonSource,
    block_id_follows,
    expected_block_id,
)
from tests.support import fake_pylon as fp

W, H = 64, 48


def open_fake(monkeypatch, camera: fp.Camera, **settings) -> PylonSource:
    fp.install(monkeypatch, camera)
    settings.setdefault("frame_timeout_s", 1.0)
    src = PylonSource("pylon:", PylonSpec(**settings), 2.0, (W, H))
    src.line_pulse = camera.ExecuteSoftwareTrigger        # the wire, for a line trigger
    return src


def trigger_of(img) -> int:
    return int(img[0, 0])


def test_an_sfnc1_camera_is_set_through_its_own_feature_names(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(then=1))
    src = open_fake(monkeypatch, cam, trigger="Line1", trigger_activation="FallingEdge",
                    trigger_delay_us=150.0, line_debouncer_us=10.0)
    assert src.names == {"ExposureTime": "ExposureTimeAbs", "Gain": "GainRaw",
                         "TriggerDelay": "TriggerDelayAbs",
                         "LineDebouncerTime": "LineDebouncerTimeAbs"}
    f = cam.features
    assert f["ExposureTimeAbs"].Value == pytest.approx(2000.0)       # microseconds
    assert src.exposure_us() == pytest.approx(2000.0)
    assert f["GainRaw"].Value == 300                # gain_db 0: the camera's least gain
    assert f["GainSelector"].Value == "All" and f["GainAuto"].Value == "Off"
    assert (f["TriggerSource"].Value, f["TriggerActivation"].Value) == ("Line1", "FallingEdge")
    assert f["TriggerDelayAbs"].Value == pytest.approx(150.0)
    assert (f["LineSelector"].Value, f["LineDebouncerTimeAbs"].Value) == ("Line1", 10.0)
    assert src.trigger_lag_us() == pytest.approx(160.0)
    for k in range(1, 4):
        assert trigger_of(src.capture()) == k
    assert src.counts() == {"frames": 3, "lost_frames": 0, "extra_triggers": 0}


def test_a_gain_in_db_on_a_gainraw_only_camera_is_one_line(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(then=1))
    with pytest.raises(ConfigError, match=r"gain_db 6: this camera sets its gain only as "
                                          r"GainRaw.*set gain_db: 0") as e:
        open_fake(monkeypatch, cam, gain_db=6.0)
    assert "\n" not in str(e.value)
    features = fp.sfnc1_features()
    features["GainAbs"] = fp.Node(0.0, 0.0, 12.0)          # models with a gain in dB
    src = open_fake(monkeypatch, fp.Camera(features, fp.counting(then=1)), gain_db=6.0)
    assert src.feature("Gain") == "GainAbs" and features["GainAbs"].Value == 6.0


def test_a_value_the_sfnc1_camera_refuses_names_its_feature(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(then=1))
    with pytest.raises(ConfigError, match=r"pylon:: LineDebouncerTimeAbs 50000.0: Value = "
                                          r"50000.0 must be equal or smaller than 20000"):
        open_fake(monkeypatch, cam, trigger="Line1", line_debouncer_us=50_000.0)
    features = fp.sfnc1_features()
    del features["LineDebouncerTimeAbs"]
    with pytest.raises(ConfigError, match="the camera has no writable LineDebouncerTime nor "
                                          "LineDebouncerTimeAbs"):
        open_fake(monkeypatch, fp.Camera(features, fp.counting(then=1)), trigger="Line1",
                  line_debouncer_us=10.0)


def test_the_block_id_rule():
    assert block_id_follows(7, 8, gige=True) and block_id_follows(7, 8, gige=False)
    assert block_id_follows(65535, 1, gige=True)          # GigE: wraps, skipping 0
    assert not block_id_follows(65535, 0, gige=True)
    assert not block_id_follows(65535, 1, gige=False)     # USB: 64 bits, no wrap
    assert block_id_follows(65535, 65536, gige=True)      # GigE extended id mode
    assert expected_block_id(65535, gige=True) == 1
    assert expected_block_id(65535, gige=False) == 65536


def test_the_gige_block_id_wraps_at_65535_without_a_false_drop(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(65533, 65534, 65535, then=1))
    src = open_fake(monkeypatch, cam)
    for k in range(1, 6):                                 # 65533 .. 65535, 1, 2
        assert trigger_of(src.capture()) == k
    assert src.last_id == 2 and src.counted
    assert src.counts() == {"frames": 5, "lost_frames": 0, "extra_triggers": 0}


def test_a_frame_lost_at_the_wrap_is_still_caught(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(65534, 65535, then=2))
    src = open_fake(monkeypatch, cam)
    src.capture()
    src.capture()
    with pytest.raises(GrabFailed, match="frame counter 2, expected 1: pair dropped"):
        src.capture()
    assert trigger_of(src.capture()) == 4                 # and the next one pairs again


def test_a_gige_camera_without_a_counter_pairs_every_frame_by_order(monkeypatch):
    """Block id 0 on GigE: "not supported by the camera", not a frame number."""
    cam = fp.Camera(fp.sfnc1_features(), itertools.repeat(0))
    src = open_fake(monkeypatch, cam)
    for k in range(1, 5):
        assert trigger_of(src.capture()) == k
    assert not src.counted
    assert src.counts() == {"frames": 4, "lost_frames": 0, "extra_triggers": 0}


def test_a_counter_standing_at_0_on_another_transport_pairs_by_order(monkeypatch):
    """USB counts from 0, so a first 0 is a frame number; a second 0 is no counter."""
    cam = fp.Camera(fp.sfnc1_features(), itertools.repeat(0), device_class="BaslerUsb")
    src = open_fake(monkeypatch, cam)
    for k in range(1, 4):
        assert trigger_of(src.capture()) == k
    assert not src.counted and src.counts()["lost_frames"] == 0


def test_an_invalid_block_id_is_not_a_gap(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(1, BLOCK_ID_INVALID, then=9))
    src = open_fake(monkeypatch, cam)
    for k in range(1, 5):                               # 1, invalid, 9, 10
        assert trigger_of(src.capture()) == k
    assert src.counted and src.counts()["lost_frames"] == 0


def test_strays_are_drained_on_a_camera_that_cannot_say_it_is_ready(monkeypatch):
    """No WaitForFrameTriggerReady (it raises): the drain still runs, after the exposure
    and a settling time; the extra trigger's frame is counted, never paired."""
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(then=1), can_wait=False)
    src = open_fake(monkeypatch, cam)
    assert trigger_of(src.capture()) == 1
    cam.ExecuteSoftwareTrigger()                          # a pulse nobody asked for
    cam.ExecuteSoftwareTrigger()                          # and another
    assert trigger_of(src.capture()) == 4
    assert src.counts() == {"frames": 2, "lost_frames": 0, "extra_triggers": 2}
    assert cam.waits == 0


def test_a_camera_that_can_wait_is_waited_for(monkeypatch):
    cam = fp.Camera(fp.sfnc1_features(), fp.counting(then=1))
    src = open_fake(monkeypatch, cam)
    src.capture()
    assert cam.waits == 2              # before the drain, and before the software trigger
