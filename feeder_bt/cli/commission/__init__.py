"""``feeder commission galil|adept|camera|plate CELL.yaml``: a guided check of a new cell.

Each step does something on the hardware, asks the person at the cell to act or to say
what they saw when only a person can tell (is the lamp on? did the belt move towards the
robot?), and records what it found; the report (YAML, or JSON for a ``.json`` name) is
written even when a step fails, so that it says how far the cell got (the robot frame is
the exception: a frame that does not fit is never written). Questions are answered on
standard input, or from ``--answers FILE`` (a YAML mapping of step keys such as
``input.jam`` to answers). Against ``feeder emulate cell`` the person's hands are the
emulator's standard input (``feeder_bt.emulators.operator``). docs/real-cell.md,
"Commissioning", has the procedure and what each step proves.

- ``galil`` (``commission.galil``): connect, firmware, threads, inputs, outputs, limit
  switches, e-stop, encoder sign by hand, latch, a powered jog per axis.
- ``adept`` (``commission.adept``): connect, vacuum and grip sensor, e-stop, encoder sync
  and drift, the robot<->cell frame from touch points (written to ``robot.frame_file``),
  the pick window's corners at low speed, each confirmed by the person.
- ``camera`` (``commission.camera``): grab, calibration from the target with its residual,
  trigger->latch->image timing with a marker riding the belt; a pylon camera also: found
  by enumeration, one frame per trigger, exposure x belt speed under half a pixel of
  blur, calibration views grabbed to files (``commission.pylon_steps``).
- ``plate`` (``commission.plate``): an AnyFeeder: connect and its echo, init, the cell's
  speeds and repetitions written and read back as answered, each action jogged once and
  confirmed by the person, the error reset, the stop.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TextIO

from feeder_bt.cli.argtypes import expect_kind, positive
from feeder_bt.cli.commission.adept import commission_adept, pick_window
from feeder_bt.cli.commission.camera import CAMERA_STEPS, commission_camera
from feeder_bt.cli.commission.galil import commission_galil
from feeder_bt.cli.commission.plate import commission_plate
from feeder_bt.cli.commission.steps import Asker, CommissionError, Report, load_answers
from feeder_bt.config import load_cell

JOG_MM_S = 20.0          # commissioning jogs are slow
INPUT_WAIT_S = 5.0       # after the person says they acted, how long to look for it


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("commission", help="guided check of a new cell: controllers, "
                                                 "I/O, limits, e-stop, latch, directions, "
                                                 "robot frame, reach, camera, timing, plate "
                                                 "feeder actions")
    p.add_argument("what", choices=["galil", "adept", "camera", "plate"])
    p.add_argument("cell", help="cell description YAML")
    p.add_argument("--answers", metavar="FILE", help="YAML mapping of step keys to answers "
                                                     "(instead of asking on standard input)")
    p.add_argument("--report", metavar="FILE", help="where to write the report (default "
                                                    "commission-WHAT.yaml; .json for JSON)")
    p.add_argument("--jog-mm-s", type=positive, default=JOG_MM_S, metavar="MM_S",
                   help="jog speed (default 20)")
    p.add_argument("--input-wait", type=positive, default=INPUT_WAIT_S, metavar="S",
                   help="seconds to look for a change after the person's answer (default 5)")
    p.add_argument("--write", metavar="FILE", help="adept: where to write the fitted robot "
                                                   "frame (default: the cell's robot.frame_file)")
    p.add_argument("--frame-limit-mm", type=positive, default=1.0, metavar="MM",
                   help="adept: largest touch-point residual rms accepted (default 1.0)")
    p.add_argument("--calibration-limit-mm", type=positive, default=0.5, metavar="MM",
                   help="camera: largest calibration residual rms accepted (default 0.5)")
    p.add_argument("--timing-limit-ms", type=positive, default=3.0, metavar="MS",
                   help="camera: largest trigger->image delay accepted (default 3)")
    p.add_argument("--steps", type=camera_steps, default=CAMERA_STEPS, metavar="A,B,...",
                   help="camera: the steps to run, of " + ",".join(CAMERA_STEPS) +
                        " (default all; enumerate, trigger, exposure and views are a pylon "
                        "camera's; timing needs the Galil)")
    p.add_argument("--belt-mm-s", type=positive, default=None, metavar="MM_S",
                   help="camera: the fastest belt speed under the camera, for the blur "
                        "check (default the latch conveyor's max_mm_s)")
    p.add_argument("--views", type=int, default=3, metavar="N",
                   help="camera (pylon): calibration views to grab to files (default 3)")
    p.add_argument("--views-dir", metavar="DIR",
                   help="camera (pylon): where the views go (default REPORT-views/)")
    p.set_defaults(handler=cmd_commission)
    return p


def camera_steps(text: str) -> tuple[str, ...]:
    """``--steps``: a comma list of camera steps, each one of ``CAMERA_STEPS``."""
    steps = tuple(t.strip() for t in text.split(",") if t.strip())
    bad = [t for t in steps if t not in CAMERA_STEPS]
    if bad or not steps:
        raise argparse.ArgumentTypeError(f"{', '.join(bad) or 'nothing'}: not a camera step; "
                                         f"one or more of {','.join(CAMERA_STEPS)}")
    return steps


STEPS = {"galil": commission_galil, "adept": commission_adept, "camera": commission_camera,
         "plate": commission_plate}


def cmd_commission(args: argparse.Namespace, stdin: TextIO | None = None,
                   out: TextIO | None = None) -> int:
    # without the calibration files: commissioning makes them (the robot frame, the camera)
    expect_kind(args.cell, "cell", "", "give the cell description it runs on (its `cell:` key names it)")
    cell = load_cell(args.cell, calibration_files=False)
    ask = Asker(load_answers(args.answers), stdin or sys.stdin, out or sys.stdout)
    report = Report(args.what, cell, out or sys.stdout)
    path = Path(args.report or f"commission-{args.what}.yaml")
    try:
        STEPS[args.what](cell, ask, report, args)
    finally:
        report.write(path)
    print(f"report: {path} ({'all steps ok' if report.ok else 'some steps FAILED'})",
          file=out or sys.stdout)
    return 0 if report.ok else 1


__all__ = ["Asker", "CommissionError", "Report", "add_parser", "cmd_commission", "pick_window"]
