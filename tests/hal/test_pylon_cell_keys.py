"""The pylon camera's cell keys (``camera.source: pylon:...``, ``camera.pylon``): checked
with file and line like every other key; a line trigger the cell fires is pulsed on the
named output once per grab. None of this needs pypylon."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import pytest

from feeder_bt.config.loader import load_cell
from feeder_bt.core.errors import ConfigError
from feeder_bt.core.jobs import DoneJob
from feeder_bt.core.model import CameraSpec


def cell_with(tmp_path, camera_lines: str):
    text = open("cells/sim.yaml").read().replace("camera:\n", "camera:\n" + camera_lines, 1)
    p = tmp_path / "cell.yaml"
    p.write_text(text)
    return p


def test_cell_file_keys_are_checked_with_file_and_line(tmp_path):
    from feeder_bt.config.loader import load_cell
    p = cell_with(tmp_path, "  source: 'pylon:'\n  pylon: {trigger: Line9, gain_db: 60}\n")
    with pytest.raises(ConfigError) as e:
        load_cell(p)
    lines = e.value.lines()
    assert any(f"{p}:" in ln and "camera.pylon.trigger" in ln and "Line1" in ln for ln in lines)
    assert any("camera.pylon.gain_db" in ln and "[0, 48]" in ln for ln in lines)


def test_camera_spec_carries_the_pylon_settings():
    cam = dataclasses.replace(CameraSpec(), source="pylon:")
    assert cam.pylon.trigger == "Software" and cam.pylon.frame_timeout_s > 0


def test_the_trigger_signal_must_be_an_output_and_a_line_trigger(tmp_path):
    p = cell_with(tmp_path, "  source: 'pylon:'\n  pylon: {trigger: Software, "
                            "trigger_signal: backlight}\n")
    with pytest.raises(ConfigError, match="camera.pylon.trigger_signal: pulses a line"):
        load_cell(p)
    p = cell_with(tmp_path, "  pylon: {trigger: Line1, trigger_signal: nowhere}\n")
    with pytest.raises(ConfigError, match="camera.pylon.trigger_signal: 'nowhere' is not an "
                                          "output in io:"):
        load_cell(p)


def test_a_line_trigger_pulses_the_named_output_once_per_grab():
    from feeder_bt.app.factory import wire_line_trigger
    cell = SimpleNamespace(camera=SimpleNamespace(pylon=SimpleNamespace(
        trigger_signal="trigger")), galil=SimpleNamespace(timeout_s=1.0))
    sets = []
    io = SimpleNamespace(set=lambda sig, v: sets.append((sig, v)) or DoneJob("io.set"))
    source = SimpleNamespace(line_pulse=None)
    wire_line_trigger(cell, source, io)
    source.line_pulse()
    assert sets == [("trigger", True), ("trigger", False)]
    bridged = SimpleNamespace(line_pulse=print)          # the emulated cell's own bridge
    wire_line_trigger(cell, bridged, io)
    assert bridged.line_pulse is print


def test_without_pypylon_a_pylon_camera_says_how_to_install_it(monkeypatch):
    import sys

    from feeder_bt.hal.camera import open_source
    monkeypatch.setitem(sys.modules, "pypylon", None)          # as if not installed
    with pytest.raises(ConfigError, match=r"camera.source: pylon: pypylon is not installed "
                                          r".*pip install -e '.\[pylon\]'"):
        open_source("pylon:", CameraSpec())


def test_the_line_trigger_keys_are_checked(tmp_path):
    p = cell_with(tmp_path, "  pylon: {trigger: Line1, trigger_activation: AnyEdge, "
                            "line_debouncer_us: -1, trigger_delay_us: 2.0e7}\n")
    with pytest.raises(ConfigError) as e:
        load_cell(p)
    lines = e.value.lines()
    assert any("camera.pylon.trigger_activation" in ln and "RisingEdge" in ln
               and "FallingEdge" in ln for ln in lines)
    assert any("camera.pylon.line_debouncer_us" in ln and "[0, 1000000]" in ln for ln in lines)
    assert any("camera.pylon.trigger_delay_us" in ln and "[0, 10000000]" in ln for ln in lines)
    p = cell_with(tmp_path, "  pylon: {trigger: Software, line_debouncer_us: 10, "
                            "trigger_delay_us: 100}\n")
    with pytest.raises(ConfigError) as e:
        load_cell(p)
    lines = e.value.lines()
    assert any("camera.pylon.line_debouncer_us: filters the trigger line: set "
               "camera.pylon.trigger to Line1" in ln for ln in lines)
    assert any("camera.pylon.trigger_delay_us: delays a line trigger" in ln for ln in lines)
    p = cell_with(tmp_path, "  pylon: {trigger: Line1, trigger_activation: FallingEdge, "
                            "line_debouncer_us: 10, trigger_delay_us: 100}\n")
    cam = load_cell(p).camera.pylon
    assert (cam.trigger_activation, cam.line_debouncer_us, cam.trigger_delay_us) == \
        ("FallingEdge", 10, 100)
