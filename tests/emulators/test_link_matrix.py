"""The emulated cell through links that die like cables: a slice of the fault proxy's matrix
(``benchmarks/link_matrix.py`` runs all of it). A link of the Galil, of the V+ motion or
position server or a plate's feeder line is silenced (a pulled cable: no FIN),
half-opened (pulled, and the device dropped the connection meanwhile), refused (the
controller gone), flooded or garbled for 4 s while parts are being picked, through a
proxy between the real drivers and the emulators; the camera's link, which lives in its
SDK, is silenced at the frame source (``emulators.dying_camera``). Every run recovers, placing again within 10 s of the link's return, or FAULTs naming the
link; nothing is lost and the world's placements equal the cell's count; and the simulated
cell given the same cut as a fault plan ends the same way (real time: soak)."""

from __future__ import annotations

import pytest

from feeder_bt.app.links import LIMIT_S, emulated, simulated

CASES = [("galil", "silence"), ("galil", "flood"), ("motion", "half_open"),
         ("motion", "garbage"), ("position", "refuse"), ("plate", "silence"),
         ("camera", "silence")]


@pytest.mark.soak
@pytest.mark.parametrize(("link", "how"), CASES)
def test_a_link_cut_for_4_s_is_recovered_and_nothing_is_lost(link, how):
    emu = emulated(link, how, 4.0)
    assert emu["lost"] == 0 and not emu["mismatch"], emu      # the world and the cell agree
    if emu["end"] == "FAULT":
        assert emu["ok"], f"a FAULT that does not name the link: {emu['fault']}"
    else:
        assert emu["placing_after_restore_s"] is not None, emu
        assert emu["placing_after_restore_s"] <= LIMIT_S, emu
    # the cut was seen: a lost link the trees met, or a reconnect of the driver's own
    assert emu["faults"].get("comms_lost", 0) + sum(emu["reconnects"].values()) >= 1, emu
    sim = simulated(link, how, 4.0)
    assert sim["end"] == emu["end"], (sim, emu)               # the simulator is not kinder
