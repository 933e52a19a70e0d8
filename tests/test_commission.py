"""``feeder commission`` against ``feeder emulate cell``: every step runs and the report
says what it found. An "operator" thread stands in for the person at the cell: it toggles
a Galil input and fires the camera trigger while the commissioning asks for them."""

from __future__ import annotations

import argparse
import io
import socket
import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from galil_fixtures import wait_until

from feeder_bt.cli import main
from feeder_bt.emulators import plant as plant_mod
from feeder_bt.tools.emulate_cmd import cmd_emulate

ROOT = Path(__file__).resolve().parent.parent


def free_block(n: int = 5) -> int:
    """A base port with ``n`` free consecutive ports after it (Galil, then V+)."""
    for base in range(23000, 60000, 97):
        socks = []
        try:
            for i in range(n):
                s = socket.socket()
                s.bind(("127.0.0.1", base + i))
                socks.append(s)
            return base
        except OSError:
            continue
        finally:
            for s in socks:
                s.close()
    raise RuntimeError("no free ports")


def write_cell(tmp_path: Path, port: int) -> Path:
    data = yaml.safe_load((ROOT / "cells" / "sim.yaml").read_text())
    data["io"]["jam"] = {"controller": "galil", "bit": 3, "dir": "in"}
    data.setdefault("galil", {})["url"] = f"socket://127.0.0.1:{port}"
    data["galil"]["timeout_s"] = 1.0
    data["adept"] = {"host": "127.0.0.1", "motion_port": port + 1, "position_port": port + 2,
                     "io_port": port + 3, "notify_port": port + 4}
    folder = tmp_path / "images"
    folder.mkdir()
    w, h = data.get("camera", {}).get("width_px", 640), data.get("camera", {}).get(
        "height_px", 484)
    cv2.imwrite(str(folder / "a.png"), np.full((h, w), 200, np.uint8))
    data.setdefault("camera", {})["source"] = str(folder)
    path = tmp_path / "cell.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture
def emulated_cell(tmp_path, monkeypatch):
    """``feeder emulate cell`` on free ports, and the plant behind it for the operator."""
    plants = []
    start = plant_mod.Plant.start

    def capture(self):
        plants.append(self)
        return start(self)
    monkeypatch.setattr(plant_mod.Plant, "start", capture)
    port = free_block()
    cell = write_cell(tmp_path, port)
    stop = threading.Event()
    args = argparse.Namespace(controller="cell", scenario=str(ROOT / "scenarios" / "lenses.yaml"),
                              cell=str(cell), port=port, host="127.0.0.1", seed=1)
    t = threading.Thread(target=cmd_emulate, args=(args, stop), daemon=True)
    t.start()
    assert wait_until(lambda: plants, timeout=5.0)
    plant = plants[0]
    done = threading.Event()

    def operator():                    # toggles the jam input and fires the trigger
        while not done.wait(0.15):
            plant.set_signal("jam", not plant.signal("jam"))
            plant.trigger()
    op = threading.Thread(target=operator, daemon=True)
    op.start()
    try:
        assert wait_until(lambda: _listening(port) and _listening(port + 1), timeout=5.0)
        yield cell, plant
    finally:
        done.set()
        stop.set()
        t.join(5.0)


def _listening(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=0.2).close()
        return True
    except OSError:
        return False


def test_commission_galil_runs_every_step_and_writes_its_report(emulated_cell, tmp_path,
                                                                capsys):
    cell, plant = emulated_cell
    answers = tmp_path / "answers.yaml"
    answers.write_text("input.jam: done\nlatch: done\ndirection.horizontal: yes\n"
                       "direction.incline: yes\nservo.horizontal: yes\nservo.incline: yes\n")
    report = tmp_path / "galil.yaml"
    code = main(["commission", "galil", str(cell), "--answers", str(answers),
                 "--report", str(report), "--input-wait", "2"])
    out = capsys.readouterr().out
    data = yaml.safe_load(report.read_text())
    steps = {s["step"]: s for s in data["steps"]}
    assert list(steps)[:5] == ["galil.connect", "galil.firmware", "galil.programs",
                               "galil.input.jam", "galil.latch"], out
    assert set(list(steps)[5:]) == {"galil.axis.horizontal", "galil.axis.incline"}
    assert code == 0 and data["ok"], out
    assert "DMC-21x3" in steps["galil.firmware"]["firmware"]
    assert steps["galil.connect"]["handle"] == "A"
    threads = steps["galil.programs"]["threads"]
    assert set(threads) == {"thread0", "thread1", "thread2"} and min(threads.values()) > 0
    assert steps["galil.input.jam"]["changes_seen"] >= 1
    assert steps["galil.latch"]["axis"] == "B" and steps["galil.latch"]["input"] == 2
    assert steps["galil.axis.horizontal"]["encoder_direction"] == "up"
    assert steps["galil.axis.horizontal"]["mm"] > 5


def test_commission_adept_and_camera_through_the_hal(emulated_cell, tmp_path):
    cell, _plant = emulated_cell
    report = tmp_path / "adept.json"
    stdin = io.StringIO("yes\nyes\n")             # answered on standard input this time
    from feeder_bt.tools.commission import add_parser
    p = argparse.ArgumentParser()
    add_parser(p.add_subparsers())
    args = p.parse_args(["commission", "adept", str(cell), "--report", str(report)])
    out = io.StringIO()
    code = args.handler(args, stdin=stdin, out=out)
    import json
    data = json.loads(report.read_text())
    steps = {s["step"]: s for s in data["steps"]}
    assert {"adept.connect", "adept.sync", "adept.drift", "adept.reach.corner1",
            "adept.reach.corner4", "adept.safe"} <= set(steps), out.getvalue()
    assert code == 0 and data["ok"], out.getvalue()
    assert abs(steps["adept.drift"]["drift_counts"]) <= 10
    assert steps["adept.drift"]["belt_mm"] > 10
    assert steps["adept.reach.corner1"]["reached"] == pytest.approx(
        steps["adept.reach.corner1"]["target"], abs=1.0)
    cam = tmp_path / "camera.yaml"
    assert main(["commission", "camera", str(cell), "--report", str(cam)]) == 0
    assert yaml.safe_load(cam.read_text())["steps"][0]["mean_grey"] == 200.0


def test_commission_reports_a_bad_answers_file_in_one_line(tmp_path, capsys):
    bad = tmp_path / "answers.yaml"
    bad.write_text("- a list\n")
    code = main(["commission", "camera", str(ROOT / "cells" / "sim.yaml"), "--answers",
                 str(bad), "--report", str(tmp_path / "r.yaml")])
    err = capsys.readouterr().err
    assert code == 2 and "answers must be a mapping" in err and "Traceback" not in err


def test_questions_are_answered_from_the_file_then_standard_input():
    from feeder_bt.tools.commission import Asker
    out = io.StringIO()
    ask = Asker({"latch": "done"}, io.StringIO("yes\n"), out)
    assert ask("latch", "Fire the trigger") == "done"             # from the answers file
    assert ask.yes("direction.horizontal", "Forward?")            # from standard input
    assert not ask.yes("direction.incline", "Forward?")           # end of input: the default
    assert "(no answer: no)" in out.getvalue()
