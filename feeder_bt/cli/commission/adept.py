"""``feeder commission adept``: the robot controller, through the HAL's ``Robot``,
``RobotPosition`` and I/O, with the person at the cell.

Connect; the vacuum output and the grip sensor (the V+ programs' vacuum switch, input 1003,
``grip.sense`` in vplus/a_server.v2, which ``HOLDING`` answers; read with ``SIG``) with and without a part against the cup, the person
confirming what the vacuum does; the e-stop input (pressed, released, polarity as the cell
says), then arm power on again; the encoder sync on a fresh, aged pair at rest
(``encoder.FreshAnchor``, the helper every run's set-up uses) and the drift after a jog;
the robot<->cell frame from touch points (``frame``), written to ``robot.frame_file`` and
sent to the controller (``FRAME``) only if its residual is within ``--frame-limit-mm``;
then, at ``SPEED 10``, the four corners of the pick window, each announced and confirmed by
the person before the next, with the arm's own ``HERE`` turned into the cell frame by the
fitted frame to check it got there (the controller's ``WHERE`` would agree with any frame
it was given, a wrong one included).
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import time
from pathlib import Path
from typing import Any

from feeder_bt.calibration.files import robot_frame_path, write_calibration_file
from feeder_bt.cli.commission.frame import FrameFit, fit_frame, frame_record, touch_points
from feeder_bt.cli.commission.steps import (
    Asker,
    Report,
    active_low,
    ensure_motor_on,
    estop_step,
    try_step,
    wait,
    wait_for,
)
from feeder_bt.config.checks import window_problems
from feeder_bt.core.clock import RealClock
from feeder_bt.core.encoder import EncoderSync, FreshAnchor, diff
from feeder_bt.core.model import CellSpec, belt_window

JOG_S = 1.0
DRIFT_TOLERANCE_MM = 0.5
CORNER_SPEED_PCT = 10.0        # SPEED 10: the first moves in a new frame are slow
REACH_TOLERANCE_MM = 1.0
REACH_MARGIN_MM = 10.0         # the corners stay this far inside the arm's reach
GRIP_SENSE = 1003              # vplus/a_server.v2: grip.sense (the vacuum switch)


def pick_window(cell: CellSpec, margin_mm: float = REACH_MARGIN_MM
                ) -> list[tuple[float, float]]:
    """Corners (cell frame, mm) of the pick window: the stretch of belt, full width, that is
    inside the robot's reach less ``margin_mm``, up to the end of the horizontal belt."""
    r = cell.robot
    bx, by = r.base_mm
    conv = cell.conveyors.get("horizontal")
    width = conv.width_mm if conv else 610.0
    length = conv.length_mm if conv else 1219.0
    dy = max(abs(0.0 - by), abs(width - by))
    reach = r.reach_mm - margin_mm
    x0 = bx - math.sqrt(max(0.0, reach ** 2 - dy ** 2))
    x1 = min(length, bx)
    return [(x0, 0.0), (x0, width), (x1, 0.0), (x1, width)]


def _signal(cell: CellSpec, name: str, direction: str) -> int | None:
    sig = cell.io.get(name)
    ok = sig is not None and sig.controller == "adept" and (sig.dir == "in") == (direction == "in")
    return sig.bit if ok else None


def commission_adept(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                     ) -> None:
    from feeder_bt.hal.adept import AdeptController
    from feeder_bt.hal.galil import make_galil
    clock = RealClock()
    ctl, conveyors, _io = make_galil(cell, clock)
    adept = None
    estop_bit = _signal(cell, "estop", "in")
    try:
        def connect() -> dict[str, Any]:
            nonlocal adept
            ctl.ready.result(cell.galil.timeout_s * 4 + 5)
            kwargs: dict[str, Any] = {}
            params = inspect.signature(AdeptController).parameters
            if "robot" in params:         # the driver sends FRAME/DEFSAFE (FRAME_SPEC)
                kwargs.update(robot=cell.robot, counts_per_mm=cell.encoder.counts_per_mm,
                              window=belt_window(cell))
            adept = AdeptController(cell.adept, clock,
                                    inputs=[estop_bit] if estop_bit is not None else [],
                                    **kwargs)
            return {"host": cell.adept.host, "galil": cell.galil.url}
        if not try_step(report, "adept.connect", connect):
            return
        assert adept is not None
        wait_s = opts.input_wait
        try_step(report, "adept.vacuum", lambda: _vacuum(cell, adept, ask, wait_s))
        if estop_bit is not None:
            low = active_low(cell, "estop")
            try_step(report, "adept.estop", lambda: _estop(adept, ask, estop_bit, low, wait_s))
        sync = EncoderSync(cell.encoder.conveyor_bits, cell.encoder.robot_bits)
        axis = cell.galil.latch_axis.upper()
        name = next(n for n, a in cell.galil.axes.items() if a.upper() == axis)
        conv = conveyors[name]
        if try_step(report, "adept.sync", lambda: _anchor(cell, conv, adept.position, sync)):
            try_step(report, "adept.drift", lambda: _drift(cell, ctl, conv, name, adept.position,
                                                           sync, ask, opts))
        fit: dict[str, FrameFit] = {}
        if not try_step(report, "adept.frame", lambda: _frame(cell, adept, ask, opts, fit)):
            return                     # no motion in a frame that is not known
        framed = dataclasses.replace(cell, robot=dataclasses.replace(
            cell.robot, base_mm=fit["fit"].base_mm))
        for i, (x, y) in enumerate(pick_window(framed), 1):
            if not try_step(report, f"adept.corner{i}",
                            lambda i=i, x=x, y=y: _corner(cell, adept, ask, fit["fit"], i, x, y)):
                break                  # the person said no, or it did not get there
        try_step(report, "adept.window", lambda: _window(framed, adept, ask, fit["fit"]))
        wait(adept.robot.set_speed(100.0), cell.adept.timeout_s + 1)
        try_step(report, "adept.safe", lambda: {"ok": wait(adept.robot.move_safe(),
                                                           cell.adept.motion_timeout_s + 1)
                                                or True})
    finally:
        if adept is not None:
            adept.close()
        ctl.close()


# ---------------------------------------------------------------------------- I/O


def _vacuum(cell: CellSpec, adept: Any, ask: Asker, wait_s: float) -> dict[str, Any]:
    bit = _signal(cell, "vacuum", "out")
    if bit is None:
        return {"ok": False, "error": "the cell names no adept output `vacuum` (io.vacuum)"}
    t = cell.adept.timeout_s + 1

    def holding() -> bool:            # what HOLDING answers: SIG(grip.sense)
        from feeder_bt.hal.adept import protocol
        return protocol.decode_flag(adept.clients["io"].call("SIG", GRIP_SENSE), "SIG")
    wait(adept.io.set(bit, True), t)
    on = ask.yes("vacuum.on", f"The vacuum (Adept output {bit}) is ON: do you hear or feel it "
                              "at the cup?")
    empty = holding()
    ask("grip.part", "Hold a part against the suction cup, then press Enter")
    gripped = wait_for(holding, wait_s, 0.1)
    ask("grip.away", "Take the part away from the cup, then press Enter")
    released = wait_for(lambda: not holding(), wait_s, 0.1)
    wait(adept.io.set(bit, False), t)
    off = ask.yes("vacuum.off", "The vacuum is OFF: has it stopped?")
    return {"ok": on and off and not empty and bool(gripped) and bool(released), "bit": bit,
            "vacuum_on_seen": on, "vacuum_off_seen": off, "sensor_without_part": empty,
            "sensor_with_part": bool(gripped), "sensor_after": not released,
            "grip_sense": GRIP_SENSE}


def _estop(adept: Any, ask: Asker, bit: int, low: bool, wait_s: float) -> dict[str, Any]:
    found = estop_step(ask, lambda: adept.io.get(bit) != low, f"Adept input {bit}", wait_s)
    ask("power.on", "Turn arm power on again at the front panel, then press Enter")
    return found


# ---------------------------------------------------------------------------- sync


def _anchor(cell: CellSpec, conv: Any, position: Any, sync: EncoderSync,
            timeout_s: float = 10.0) -> dict[str, Any]:
    wait(conv.stop(), 10.0)
    anchor = FreshAnchor(cell.encoder.conveyor_bits, cell.encoder.robot_bits)
    pair = wait_for(lambda: anchor.offer(time.monotonic(), conv.position(), conv.position_age(),
                                         position.belt_encoder(), position.age()),
                    timeout_s, 0.05)
    if not pair:
        raise RuntimeError(f"no fresh pair of counts at rest in {timeout_s:g} s: {anchor.why}")
    sync.reset(*pair)
    return {"galil": pair[0], "robot": pair[1]}


def _drift(cell: CellSpec, ctl: Any, conv: Any, name: str, position: Any, sync: EncoderSync,
           ask: Asker, opts: argparse.Namespace) -> dict[str, Any]:
    anchored = sync.reference
    assert anchored is not None
    if not ensure_motor_on(ctl, conv, name, ask, cell.galil.timeout_s + 1):
        return {"ok": False, "error": "motor off (left off)"}
    # twice the jog, within the belt's limit (the driver refuses a speed above it)
    wait(conv.set_speed(min(opts.jog_mm_s * 2, cell.conveyors[name].max_mm_s)), 10.0)
    time.sleep(JOG_S * 2)
    check = EncoderSync(cell.encoder.conveyor_bits, cell.encoder.robot_bits)
    _anchor(cell, conv, position, check)                  # a fresh pair at rest again
    g, r = check.reference                                # type: ignore[misc]
    counts = sync.robot_diff(r, sync.to_robot(g))
    tol = DRIFT_TOLERANCE_MM * cell.encoder.counts_per_mm
    return {"ok": abs(counts) <= tol, "drift_counts": counts,
            "drift_mm": round(counts / cell.encoder.counts_per_mm, 3),
            "belt_mm": round(diff(g, anchored[0], cell.encoder.conveyor_bits)
                             / cell.encoder.counts_per_mm, 1),
            "tolerance_counts": round(tol, 1)}


# ---------------------------------------------------------------------------- frame


def _here(adept: Any) -> tuple[float, float]:
    """``HERE`` on the position socket: the tool in the robot's own world frame."""
    values = adept.clients["position"].call("HERE")
    return float(values[0]), float(values[1])


def _frame(cell: CellSpec, adept: Any, ask: Asker, opts: argparse.Namespace,
           out: dict[str, FrameFit]) -> dict[str, Any]:
    points = touch_points(cell, pick_window(cell))
    robot_pts = []
    for i, (x, y) in enumerate(points, 1):
        ask(f"touch.{i}", f"With the pendant, jog the tool tip onto mark {i} at cell x {x:.1f}, "
                          f"y {y:.1f} mm (belt frame), then press Enter")
        robot_pts.append(_here(adept))
    fit = fit_frame(points, robot_pts)
    had_deg = float(getattr(cell.robot, "base_deg", 0.0))
    found: dict[str, Any] = {
        "base_mm": [round(fit.base_mm[0], 3), round(fit.base_mm[1], 3)],
        "base_deg": round(fit.base_deg, 4), "rms_mm": round(fit.rms_mm, 3),
        "max_mm": round(fit.max_mm, 3), "limit_mm": opts.frame_limit_mm,
        "points": len(points),
        "change_from_cell_file": {"dx_mm": round(fit.base_mm[0] - cell.robot.base_mm[0], 3),
                                  "dy_mm": round(fit.base_mm[1] - cell.robot.base_mm[1], 3),
                                  "ddeg": round(fit.base_deg - had_deg, 4)}}
    if fit.rms_mm > opts.frame_limit_mm:
        found.update(ok=False, written=None, error=(
            f"touch residual {fit.rms_mm:.2f} mm over {opts.frame_limit_mm:g} mm: the marks, "
            "the touches or the tool are off; nothing written"))
        return found
    dest = Path(opts.write) if opts.write else robot_frame_path(cell)
    if dest is not None:
        header = (f"feeder commission adept {cell.path}: the robot base in the cell frame.\n"
                  "Name this file as robot.frame_file in the cell description.")
        write_calibration_file(dest, frame_record(fit, points, robot_pts), header)
    found["written"] = str(dest) if dest is not None else None
    if dest is None:
        found["note"] = "not written: name robot.frame_file in the cell or give --write FILE"
    # the controller moves in the frame just found (FRAME_SPEC: FRAME x y rz)
    adept.clients["motion"].call("FRAME", fit.base_mm[0], fit.base_mm[1], fit.base_deg)
    out["fit"] = fit
    return found


def _corner(cell: CellSpec, adept: Any, ask: Asker, fit: FrameFit, i: int, x: float, y: float
            ) -> dict[str, Any]:
    from feeder_bt.hal.interfaces import Pose
    if not ask.yes(f"corner.{i}.go", f"The arm will move at {CORNER_SPEED_PCT:g} % speed to "
                                     f"corner {i} of the pick window, cell x {x:.0f}, y {y:.0f} "
                                     f"mm, {cell.robot.approach_mm:g} mm up. Clear to move?"):
        return {"ok": False, "target": [round(x, 1), round(y, 1)], "error": "not cleared"}
    wait(adept.robot.set_speed(CORNER_SPEED_PCT), cell.adept.timeout_s + 1)
    wait(adept.robot.move_to(Pose(x, y, cell.robot.approach_mm)),
         cell.adept.motion_timeout_s * 10 + 1)              # 10 % speed: ten times as long
    got = fit.to_cell(_here(adept))
    there = math.dist(got, (x, y)) <= REACH_TOLERANCE_MM
    seen = ask.yes(f"corner.{i}.ok", f"Is the tool over corner {i} of the pick window?")
    return {"ok": there and seen, "target": [round(x, 1), round(y, 1)],
            "reached_cell": [round(got[0], 1), round(got[1], 1)], "person_confirms": seen}


# ---------------------------------------------------------------------------- window

WINDOW_TOLERANCE_MM = 5.0     # a taught limit this far from the cell file's is news


def _window(cell: CellSpec, adept: Any, ask: Asker, fit: FrameFit) -> dict[str, Any]:
    """The belt window taught as Adept's belt calibration teaches it: the person touches
    the tool on the belt at the upstream limit, the downstream limit and the pick limit;
    each touch (``HERE``, through the fitted frame) gives a belt-frame x. Refused when a
    limit is outside the arm's reach over the belt or out of order; else sent to the
    controller (WINDOW) and reported with the cell file lines that hold it."""
    conv = cell.conveyors.get("horizontal")
    y = (conv.width_mm if conv else 610.0) / 2
    had = belt_window(cell)
    names = ("upstream limit (where tracking may begin)",
             "downstream limit (the arm never follows the belt past it)",
             "pick limit (no pick starts for a part past it)")
    taught = []
    for key, name, x in zip(("up", "down", "pick"), names, had, strict=True):
        ask(f"window.{key}", f"With the pendant, jog the tool tip onto the belt at the "
                             f"{name}; the cell file has it at x {x:.1f}, y {y:.1f} mm "
                             "(belt frame). Then press Enter")
        taught.append(round(fit.to_cell(_here(adept))[0], 1))
    up, down, pick = taught
    found: dict[str, Any] = {
        "taught_mm": taught, "cell_file_mm": [round(v, 1) for v in had],
        "change_mm": [round(t - h, 1) for t, h in zip(taught, had, strict=True)]}
    problems = window_problems(cell, up, down, pick)
    if problems:
        found.update(ok=False, error="; ".join(problems) + ": not sent")
        return found
    adept.clients["motion"].call("WINDOW", up, down, pick)
    moved = any(abs(c) > WINDOW_TOLERANCE_MM for c in found["change_mm"])
    found.update(ok=True, sent=True, cell_file_lines=[
        f"robot.belt_window_mm: [{up:g}, {down:g}]", f"robot.pick_limit_mm: {pick:g}"],
        note=("differs from the cell file by over "
              f"{WINDOW_TOLERANCE_MM:g} mm: put these lines in it") if moved else
        "agrees with the cell file")
    return found
