"""What would only show in a run is named by ``feeder check`` first: an opening wider than
any part, a closing wider than the image, a place pose out of the arm's reach, a name that
is not text, a FIFO or a file of megabytes where a YAML file belongs."""

from __future__ import annotations

import os
import threading
from pathlib import Path

from feeder_bt.config import check_files

ROOT = Path(__file__).resolve().parents[2]
LENSES = (ROOT / "scenarios" / "lenses.yaml").read_text()


def _scenario(tmp_path: Path, text: str) -> str:
    p = tmp_path / "s.yaml"
    p.write_text(text.replace("cell: ../cells/sim.yaml", f"cell: {ROOT / 'cells' / 'sim.yaml'}"))
    return str(p)


def test_the_shipped_lenses_pass(tmp_path):
    assert check_files([_scenario(tmp_path, LENSES)]) == []


def test_an_opening_wider_than_any_part_is_refused(tmp_path):
    out = check_files([_scenario(tmp_path, LENSES.replace("open_px: 3", "open_px: 100000"))])
    assert len(out) == 1 and "vision.morphology.open_px: must be < 53 px" in out[0]
    assert "erases every part" in out[0]


def test_an_opening_just_under_the_part_passes_and_at_it_is_refused(tmp_path):
    assert check_files([_scenario(tmp_path, LENSES.replace("open_px: 3", "open_px: 52"))]) == []
    assert check_files([_scenario(tmp_path, LENSES.replace("open_px: 3", "open_px: 53"))])


def test_a_closing_wider_than_the_image_is_refused(tmp_path):
    out = check_files([_scenario(tmp_path, LENSES.replace("close_px: 3", "close_px: 484"))])
    assert len(out) == 1 and "vision.morphology.close_px: must be < 484 px" in out[0]


def test_a_place_out_of_reach_is_refused(tmp_path):
    text = LENSES.replace("place: {x: 1330, y: -120", "place: {x: 1000000000, y: -120")
    out = check_files([_scenario(tmp_path, text)])
    assert len(out) == 1 and "parts.lens.place" in out[0] and "outside its reach" in out[0]
    under = LENSES.replace("place: {x: 1330, y: -120", "place: {x: 1370, y: 300")  # the base
    out = check_files([_scenario(tmp_path, under)])
    assert len(out) == 1 and "is 5 mm from the robot base" in out[0]


def test_a_name_with_a_lone_surrogate_is_one_line(tmp_path):
    text = "\n".join('name: "lens\\ud800"' if ln.startswith("name:") else ln
                     for ln in LENSES.splitlines())
    out = check_files([_scenario(tmp_path, text)])
    assert len(out) == 1 and "name: not valid text: a lone surrogate" in out[0]
    out[0].encode("utf-8")                        # the message itself prints anywhere


def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "fifo.yaml"
    os.mkfifo(fifo)
    got: list[list[str]] = []
    t = threading.Thread(target=lambda: got.append(check_files([str(fifo)])), daemon=True)
    t.start()
    t.join(60)
    if t.is_alive():                              # unblock the reader before failing
        with open(fifo, "w") as w:
            w.write("name: x\n")
    assert got and "is not a regular file" in got[0][0]


def test_a_file_of_megabytes_is_refused_unread(tmp_path):
    big = tmp_path / "big.yaml"
    big.write_text("name: x\n" + "#" * (3 * 2**20))
    out = check_files([str(big)])
    assert len(out) == 1 and "is 3.0 MiB" in out[0] and "at most 1 MiB" in out[0]
