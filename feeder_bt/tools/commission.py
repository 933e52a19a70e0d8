"""``feeder commission galil|adept|camera CELL.yaml``: a guided check of a new cell.

Each step does something on the hardware, asks the person at the cell what they saw when
only a person can tell (did the belt move towards the robot? is the input toggled?), and
records what it found; the report (YAML, or JSON for a ``.json`` name) is written even
when a step fails, so that it says how far the cell got. Questions are answered on
standard input, or from ``--answers FILE`` (a YAML mapping of step keys such as
``input.jam`` or ``direction.horizontal`` to answers) for a rehearsal against
``feeder emulate cell``. docs/real-cell.md has the checklist and what each step proves.

- ``galil``: connect (handle, ``CF``), firmware (``^R^V``), the card's program threads
  (``_XQ``), each Galil input toggled by the user, the latch (camera trigger on the fixed
  latch input), and per axis: motor on, a short jog, encoder direction and the user's
  word on the belt direction.
- ``adept`` (through the HAL's ``Robot`` and ``RobotPosition`` only): connect, belt
  encoder sync anchored on fresh counts at rest, drift between the Galil's and the
  robot's counters after a jog, and the robot's reach to the corners of the pick window.
- ``camera``: a grab from ``camera.source``, its size against the cell description.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import yaml

from ..argtypes import positive
from ..clock import RealClock
from ..encoder import EncoderSync, diff
from ..errors import FeederError
from ..jobs import Job, JobState
from ..scenario import load_cell
from ..scenario.model import CellSpec

JOG_MM_S = 20.0          # commissioning jogs are slow
JOG_S = 1.0
INPUT_WAIT_S = 5.0       # after the user says an input was toggled, how long to look for it
DRIFT_TOLERANCE_MM = 0.5


class CommissionError(FeederError):
    exit_code = 2


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("commission", help="guided check of a new cell: controllers, "
                                                 "inputs, latch, directions, sync, reach, camera")
    p.add_argument("what", choices=["galil", "adept", "camera"])
    p.add_argument("cell", help="cell description YAML")
    p.add_argument("--answers", metavar="FILE", help="YAML mapping of step keys to answers "
                                                     "(instead of asking on standard input)")
    p.add_argument("--report", metavar="FILE", help="where to write the report (default "
                                                    "commission-WHAT.yaml; .json for JSON)")
    p.add_argument("--jog-mm-s", type=positive, default=JOG_MM_S, metavar="MM_S",
                   help="jog speed (default 20)")
    p.add_argument("--input-wait", type=positive, default=INPUT_WAIT_S, metavar="S",
                   help="seconds to look for an input change after the answer (default 5)")
    p.set_defaults(handler=cmd_commission)
    return p


# ---------------------------------------------------------------------------- asking


class Asker:
    """Questions to the person at the cell: from the answers file, else standard input."""

    def __init__(self, answers: dict[str, Any], stdin: TextIO, out: TextIO) -> None:
        self.answers, self.stdin, self.out = answers, stdin, out

    def __call__(self, key: str, question: str, default: str = "") -> str:
        if key in self.answers:
            answer = str(self.answers[key])
            print(f"{question} [{key}] -> {answer}", file=self.out, flush=True)
            return answer
        print(f"{question} [{key}] ", end="", file=self.out, flush=True)
        line = self.stdin.readline()
        answer = line.strip() if line else default
        if not line:
            print(f"(no answer: {default or 'nothing'})", file=self.out, flush=True)
        return answer

    def yes(self, key: str, question: str) -> bool:
        return self(key, f"{question} [yes/no]", "no").strip().lower() in ("y", "yes", "true")


def load_answers(path: str | None) -> dict[str, Any]:
    if not path:
        return {}
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise CommissionError(f"{p}: cannot read answers: {e.strerror or e}") from None
    except yaml.YAMLError as e:
        raise CommissionError(f"{p}: not YAML: {str(e).splitlines()[0]}") from None
    if not isinstance(data, dict):
        raise CommissionError(f"{p}: answers must be a mapping of step keys to answers")
    return {str(k): v for k, v in data.items()}


class Report:
    """The steps and what each found; written as YAML or JSON."""

    def __init__(self, what: str, cell: CellSpec, out: TextIO) -> None:
        self.out = out
        self.data: dict[str, Any] = {
            "commission": what, "cell": cell.name, "cell_file": str(cell.path),
            "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "steps": []}

    def step(self, name: str, ok: bool, **found: Any) -> bool:
        self.data["steps"].append({"step": name, "ok": bool(ok), **found})
        detail = ", ".join(f"{k}={v}" for k, v in found.items())
        print(f"{'ok  ' if ok else 'FAIL'} {name}: {detail}", file=self.out, flush=True)
        return ok

    @property
    def ok(self) -> bool:
        return all(s["ok"] for s in self.data["steps"]) and bool(self.data["steps"])

    def write(self, path: Path) -> None:
        self.data["ok"] = self.ok
        text = (json.dumps(self.data, indent=2) if path.suffix == ".json"
                else yaml.safe_dump(self.data, sort_keys=False))
        try:
            path.write_text(text, encoding="utf-8")
        except OSError as e:
            raise CommissionError(f"{path}: cannot write the report: {e.strerror or e}") from None


def wait(job: Job, timeout: float) -> Any:
    """Poll a HAL job until it ends; its result, or raise its error (or a time-out)."""
    end = time.monotonic() + timeout
    while not job.done and time.monotonic() < end:
        time.sleep(0.01)
    if job.state is JobState.SUCCEEDED:
        return job.result
    raise job.error if job.error is not None else TimeoutError(f"{job.name}: no end in "
                                                               f"{timeout:g} s")


def _try(report: Report, name: str, fn: Callable[[], dict[str, Any]]) -> bool:
    """Run one step; an exception is that step's failure, in one line."""
    try:
        found = fn()
    except Exception as e:                       # noqa: BLE001 - any failure is a finding
        return report.step(name, False, error=f"{type(e).__name__}: {e}")
    ok = bool(found.pop("ok", True))
    return report.step(name, ok, **found)


# ---------------------------------------------------------------------------- galil


def commission_galil(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                     ) -> None:
    from ..hal.galil import make_galil
    ctl, conveyors, io = make_galil(cell, RealClock())
    try:
        def connect() -> dict[str, Any]:
            ctl.ready.result(cell.galil.timeout_s * 4 + 5)
            return {"url": cell.galil.url, "handle": ctl.handle or "serial",
                    "servo": ctl.servo_refused or "on"}
        if not _try(report, "galil.connect", connect):
            return

        def firmware() -> dict[str, Any]:
            text = ctl.command("\x12\x16").result(cell.galil.timeout_s + 1).strip()
            ctl.firmware = text
            return {"ok": "DMC" in text, "firmware": text}
        _try(report, "galil.firmware", firmware)

        def threads() -> dict[str, Any]:
            end = time.monotonic() + 2.0
            while len(ctl.thread_lines) < 3 and time.monotonic() < end:
                time.sleep(0.05)
            lines = dict(ctl.thread_lines)
            return {"ok": bool(lines) and all(v >= 0 for v in lines.values())
                    and not ctl.program_errors,
                    "threads": {f"thread{k}": v for k, v in sorted(lines.items())},
                    "program_errors": list(ctl.program_errors)}
        _try(report, "galil.programs", threads)

        for name, bit in sorted(io.inputs.items(), key=lambda kv: kv[1]):
            _try(report, f"galil.input.{name}", lambda n=name, b=bit: _input(io, ask, n, b,
                                                                              opts.input_wait))
        _try(report, "galil.latch", lambda: _latch(cell, conveyors, ctl, ask))
        for name, conv in conveyors.items():
            _try(report, f"galil.axis.{name}", lambda n=name, c=conv: _axis(cell, ctl, n, c,
                                                                             ask, opts))
    finally:
        ctl.close()


def _input(io: Any, ask: Asker, name: str, bit: int, wait_s: float) -> dict[str, Any]:
    io.changes()                                  # forget what came before the question
    before = io.get(name)
    ask(f"input.{name}", f"Toggle input {name!r} (Galil input {bit}) now, then press Enter")
    end = time.monotonic() + wait_s
    seen: list[bool] = []
    while time.monotonic() < end and not seen:
        seen = [c.value for c in io.changes() if c.signal == name]
        time.sleep(0.02)
    return {"ok": bool(seen), "bit": bit, "was": before, "changes_seen": len(seen)}


def _latch(cell: CellSpec, conveyors: dict[str, Any], ctl: Any, ask: Asker
           ) -> dict[str, Any]:
    g = cell.galil
    axis = g.latch_axis.upper()
    name = next((n for n, a in g.axes.items() if a.upper() == axis), None)
    if name is None:
        return {"ok": False, "error": f"no conveyor on the latch axis {axis}"}
    conv = conveyors[name]
    wait(conv.arm_latch(), g.timeout_s + 1)
    ask("latch", f"Fire the camera trigger once (latch input {g.latch_input or 'of ' + axis}), "
                 f"then press Enter")
    count = wait(conv.read_latch(timeout_s=5.0), 7.0)
    return {"axis": axis, "input": g.latch_input or "ABCDEFGH".index(axis) + 1,
            "latched": count, "position_now": ctl.position(axis)}


def _axis(cell: CellSpec, ctl: Any, name: str, conv: Any, ask: Asker,
          opts: argparse.Namespace) -> dict[str, Any]:
    axis = conv.axis
    st = ctl.status(axis)
    if st is None or st.motor_off:
        if not ask.yes(f"servo.{name}", f"The motor of {name} (axis {axis}) is off. Turn it on?"):
            return {"ok": False, "axis": axis, "motor": "off (left off)"}
        wait(conv.servo(True), cell.galil.timeout_s + 1)
    before = ctl.submit(ctl.read_position, axis).result(cell.galil.timeout_s + 1)
    wait(conv.set_speed(opts.jog_mm_s), 10.0)
    time.sleep(JOG_S)
    wait(conv.stop(), 10.0)
    after = ctl.submit(ctl.read_position, axis).result(cell.galil.timeout_s + 1)
    moved = diff(after, before, cell.encoder.conveyor_bits)
    forward = ask.yes(f"direction.{name}", f"Did the {name} belt move forward (towards the "
                                            f"robot) just now?")
    mm = moved / cell.encoder.counts_per_mm
    return {"ok": moved > 0 and forward, "axis": axis, "counts": moved, "mm": round(mm, 2),
            "encoder_direction": "up" if moved > 0 else "down" if moved < 0 else "none",
            "belt_forward": forward}


# ---------------------------------------------------------------------------- adept


def pick_window(cell: CellSpec) -> list[tuple[float, float]]:
    """Corners (belt frame, mm) of the pick window: the stretch of belt, full width, that is
    inside the robot's reach, up to the end of the horizontal belt."""
    r = cell.robot
    bx, by = r.base_mm
    conv = cell.conveyors.get("horizontal")
    width = conv.width_mm if conv else 610.0
    length = conv.length_mm if conv else 1219.0
    dy = max(abs(0.0 - by), abs(width - by))
    x0 = bx - math.sqrt(max(0.0, r.reach_mm ** 2 - dy ** 2))
    x1 = min(length, bx)
    return [(x0, 0.0), (x0, width), (x1, 0.0), (x1, width)]


def commission_adept(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                     ) -> None:
    from ..hal.adept import AdeptController
    from ..hal.galil import make_galil
    from ..hal.interfaces import Pose
    clock = RealClock()
    ctl, conveyors, _io = make_galil(cell, clock)
    adept = None
    try:
        def connect() -> dict[str, Any]:
            nonlocal adept
            ctl.ready.result(cell.galil.timeout_s * 4 + 5)
            adept = AdeptController(cell.adept, clock, robot=cell.robot,
                                    counts_per_mm=cell.encoder.counts_per_mm)
            return {"host": cell.adept.host, "galil": cell.galil.url}
        if not _try(report, "adept.connect", connect):
            return
        robot, position = adept.robot, adept.position       # the HAL interfaces only
        axis = cell.galil.latch_axis.upper()
        name = next(n for n, a in cell.galil.axes.items() if a.upper() == axis)
        conv = conveyors[name]
        sync = EncoderSync(cell.encoder.conveyor_bits, cell.encoder.robot_bits)
        anchored: dict[str, int] = {}

        def fresh_pair() -> tuple[int, int]:
            """Both counts with the belt at rest, each read fresh: the robot's twice, 0.3 s
            apart (its cache refreshed between), equal, around a TP read of the Galil's."""
            for _ in range(10):
                time.sleep(0.3)
                r1 = position.belt_encoder()
                g = ctl.submit(ctl.read_position, axis).result(cell.galil.timeout_s + 1)
                time.sleep(0.3)
                if position.belt_encoder() == r1:
                    return g, r1
            raise RuntimeError("the robot's belt count does not settle: is the belt moving?")

        def anchor() -> dict[str, Any]:
            wait(conv.stop(), 10.0)
            g, r = fresh_pair()
            sync.reset(g, r)
            anchored.update(galil=g, robot=r)
            return {"galil": g, "robot": r}
        if not _try(report, "adept.sync", anchor):
            return

        def drift() -> dict[str, Any]:
            st = ctl.status(axis)
            if st is None or st.motor_off:
                if not ask.yes(f"servo.{name}", f"The motor of {name} is off. Turn it on?"):
                    return {"ok": False, "error": "motor off"}
                wait(conv.servo(True), cell.galil.timeout_s + 1)
            # twice the jog, within the belt's limit (the driver refuses a speed above it)
            wait(conv.set_speed(min(opts.jog_mm_s * 2, cell.conveyors[name].max_mm_s)), 10.0)
            time.sleep(JOG_S * 2)
            wait(conv.stop(), 10.0)
            g, r = fresh_pair()
            predicted = sync.to_robot(g)
            counts = sync.robot_diff(r, predicted)
            tol = DRIFT_TOLERANCE_MM * cell.encoder.counts_per_mm
            return {"ok": abs(counts) <= tol, "drift_counts": counts,
                    "drift_mm": round(counts / cell.encoder.counts_per_mm, 3),
                    "belt_mm": round(diff(g, anchored["galil"], cell.encoder.conveyor_bits)
                                     / cell.encoder.counts_per_mm, 1),
                    "tolerance_counts": round(tol, 1)}
        _try(report, "adept.drift", drift)

        for i, (x, y) in enumerate(pick_window(cell)):
            def reach(x: float = x, y: float = y) -> dict[str, Any]:
                pose = Pose(x, y, cell.robot.approach_mm)
                wait(robot.move_to(pose), cell.adept.motion_timeout_s + 1)
                end = time.monotonic() + 2.0           # the position cache lags the arm
                got = position.pose()
                while math.dist((got.x, got.y), (x, y)) > 1.0 and time.monotonic() < end:
                    time.sleep(0.05)
                    got = position.pose()
                return {"ok": math.dist((got.x, got.y), (x, y)) <= 1.0,
                        "target": [round(x, 1), round(y, 1)],
                        "reached": [round(got.x, 1), round(got.y, 1)]}
            _try(report, f"adept.reach.corner{i + 1}", reach)
        _try(report, "adept.safe", lambda: {"ok": wait(robot.move_safe(),
                                                       cell.adept.motion_timeout_s + 1) or True})
    finally:
        if adept is not None:
            adept.close()
        ctl.close()


# ---------------------------------------------------------------------------- camera


def commission_camera(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                      ) -> None:
    from ..hal.camera import open_source
    src = None

    def grab() -> dict[str, Any]:
        nonlocal src
        src = open_source(cell.camera.source)
        t0 = time.monotonic()
        img = src.capture()
        h, w = img.shape[:2]
        want = (cell.camera.width_px, cell.camera.height_px)
        return {"ok": (w, h) == want, "source": cell.camera.source, "size": [w, h],
                "expected": list(want), "mean_grey": round(float(img.mean()), 1),
                "grab_s": round(time.monotonic() - t0, 3)}
    try:
        _try(report, "camera.grab", grab)
    finally:
        if src is not None:
            src.close()


STEPS = {"galil": commission_galil, "adept": commission_adept, "camera": commission_camera}


def cmd_commission(args: argparse.Namespace, stdin: TextIO | None = None,
                   out: TextIO | None = None) -> int:
    cell = load_cell(args.cell)
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
