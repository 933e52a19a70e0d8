"""``feeder commission camera``: a grab, the calibration with its residual, and the timing
from the camera trigger to the latched count to the exposure.

The timing step: with the belt stopped the person puts a round marker on the belt upstream
of the view; a frame at rest ties the marker's image position to the latched count. Then
the belt runs and each triggered frame gives the marker's image position and the count
latched at its trigger. If the exposure came ``d`` seconds after the trigger, the marker is
``d * v`` further on than the latched count says; an encoder scale error adds a term that
grows with the distance run instead. Two passes at two speeds separate the two by least
squares (``r = a * travelled + d * v``): ``d`` is reported in ms, ``d * v`` in mm at the
faster speed, and the step fails over ``--timing-limit-ms``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import cv2
import numpy as np

from feeder_bt.calibration import DEFAULT_TARGETS, calibrate_camera_image
from feeder_bt.calibration.belt import TRAVEL_LIMIT_DEG, travel_deg
from feeder_bt.calibration.camera import Target, centred_pose
from feeder_bt.cli.commission.steps import Asker, Report, ensure_motor_on, try_step, wait
from feeder_bt.core.clock import RealClock
from feeder_bt.core.encoder import diff
from feeder_bt.core.model import CameraCalibration, CellSpec
from feeder_bt.vision.pixels import Calibration, turned_about

TIMING_SPEEDS_MM_S = (100.0, 200.0)
FRAME_GAP_S = 0.15           # between triggered frames while the marker crosses the view
MAX_FRAMES = 12              # per pass
MARKER_IN_MM = 60.0          # the marker goes this far inside the upstream edge of the view
MARKER_AREA_MM2 = (150.0, 800.0)   # a 20 mm disc is 314 mm^2; other blobs are not the marker
CAMERA_STEPS = ("enumerate", "grab", "trigger", "exposure", "views", "calibration", "timing")


def cell_target(cell: CellSpec) -> Target:
    """The cell's calibration target (``camera.target``), else the default chessboard."""
    spec = cell.camera.target
    if spec is None:
        return DEFAULT_TARGETS["chessboard"]
    return Target(spec.kind, spec.board[0], spec.board[1], spec.pitch_mm, spec.dot_mm,
                  spec.marker_mm, spec.dictionary)


def open_camera(spec: str, cell: CellSpec | None = None) -> Any:
    """``camera.source``; ``emulated-camera://HOST:PORT`` is ``feeder emulate cell``'s."""
    from feeder_bt.emulators.camera_server import CameraClient
    if spec.startswith(CameraClient.SCHEME):
        return CameraClient(spec)
    from feeder_bt.hal.camera import open_source
    return open_source(spec, cell.camera if cell is not None else None)


def commission_camera(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace
                      ) -> None:
    src = None
    cal: dict[str, CameraCalibration] = {"now": cell.camera.calibration}
    centre: dict[str, tuple[float, float]] = {}      # the target's, once calibrated

    def grab() -> dict[str, Any]:
        nonlocal src
        src = open_camera(cell.camera.source, cell)
        t0 = time.monotonic()
        img = src.capture()
        h, w = img.shape[:2]
        want = (cell.camera.width_px, cell.camera.height_px)
        return {"ok": (w, h) == want, "source": cell.camera.source, "size": [w, h],
                "expected": list(want), "mean_grey": round(float(img.mean()), 1),
                "grab_s": round(time.monotonic() - t0, 3)}

    def calibrate() -> dict[str, Any]:
        cam = cell.camera
        target = cell_target(cell)
        pose = centred_pose(cam.calibration, cam.width_px, cam.height_px)
        ask("target.lay", f"Stop the belt and lay the {target.describe()} centred at cell "
                          f"x {pose.x_mm:.1f}, y {pose.y_mm:.1f} mm, {pose.angle_deg:g} deg, "
                          "then press Enter")
        fit = calibrate_camera_image(src.capture(), target, pose, cam.calibration)
        centre["mm"] = (pose.x_mm, pose.y_mm)
        ask("target.remove", "Take the target away, then press Enter")
        values = fit.as_dict()
        ok = fit.rms_mm <= opts.calibration_limit_mm
        if ok:
            cal["now"] = fit.calibration
        return {"ok": ok, "rms_mm": round(fit.rms_mm, 4), "max_mm": round(fit.max_mm, 4),
                "limit_mm": opts.calibration_limit_mm, "points": fit.n_points,
                "calibration": {k: values[k] for k in ("origin_mm", "mm_per_px",
                                                       "rotation_deg")},
                "hint": fit.hint or ""}

    wanted = set(getattr(opts, "steps", CAMERA_STEPS))
    pylon = cell.camera.source.startswith("pylon:")
    try:
        if pylon and "enumerate" in wanted:
            from feeder_bt.cli.commission.pylon_steps import enumerate_step
            if not try_step(report, "camera.pylon.enumerate", lambda: enumerate_step(cell)):
                return
        if not try_step(report, "camera.grab", grab):
            return
        if pylon:
            from feeder_bt.cli.commission.pylon_steps import pylon_steps
            pylon_steps(cell, ask, report, opts, src, wanted)
        if "calibration" in wanted:
            try_step(report, "camera.calibration", calibrate)
        if "timing" in wanted:
            try_step(report, "camera.timing",
                     lambda: _timing(cell, ask, src, cal["now"], opts, centre.get("mm")))
    finally:
        if src is not None:
            src.close()


def find_marker(img: np.ndarray, calibration: CameraCalibration) -> tuple[float, float] | None:
    """The round marker's centre in cell mm, or None when it is not wholly in view."""
    dark = (img < 0.5 * float(np.median(img))).astype(np.uint8)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(dark, connectivity=8)
    s = calibration.mm_per_px
    h, w = img.shape[:2]
    best = None
    for i in range(1, n):
        x, y, bw, bh, area = stats[i]
        if not MARKER_AREA_MM2[0] <= area * s * s <= MARKER_AREA_MM2[1]:
            continue
        if x <= 1 or y <= 1 or x + bw >= w - 1 or y + bh >= h - 1:
            continue                                   # cut by the border: biased
        if best is None or area > stats[best][4]:
            best = i
    if best is None:
        return None
    mm = Calibration(calibration).px_to_mm(centroids[best][None, :])[0]
    return float(mm[0]), float(mm[1])


def _timing(cell: CellSpec, ask: Asker, src: Any, calibration: CameraCalibration,
            opts: argparse.Namespace, centre_mm: tuple[float, float] | None = None
            ) -> dict[str, Any]:
    from feeder_bt.hal.galil import make_galil
    g = cell.galil
    axis = g.latch_axis.upper()
    name = next((n for n, a in g.axes.items() if a.upper() == axis), None)
    if name is None:
        return {"ok": False, "error": f"no conveyor on the latch axis {axis}"}
    ctl, conveyors, _io = make_galil(cell, RealClock())
    conv = conveyors[name]
    cpm = cell.encoder.counts_per_mm
    t = g.timeout_s + 1
    rows: list[tuple[float, float, float]] = []          # travelled mm, speed, residual mm
    moves: list[tuple[float, float]] = []                 # the marker's, from where it rested
    try:
        ctl.ready.result(g.timeout_s * 4 + 5)
        if not ensure_motor_on(ctl, conv, name, ask, t):
            return {"ok": False, "error": "motor off (left off)"}

        def shot() -> tuple[int, tuple[float, float] | None]:
            wait(conv.arm_latch(), t)
            img = src.capture()                           # the trigger latches the count
            return wait(conv.read_latch(timeout_s=5.0), 7.0), find_marker(img, calibration)

        x_in = calibration.origin_mm[0] + MARKER_IN_MM
        y_mid = cell.conveyors["horizontal"].width_mm / 2 if "horizontal" in cell.conveyors \
            else 305.0
        speeds = [min(v, cell.conveyors[name].max_mm_s) for v in TIMING_SPEEDS_MM_S]
        for k, v in enumerate(speeds, 1):
            wait(conv.stop(), 10.0)
            ask(f"marker.{k}", f"Belt stopped. Put the round marker on the belt at cell "
                               f"x {x_in:.0f}, y {y_mid:.0f} mm, then press Enter")
            c0, m0 = shot()
            if m0 is None:
                return {"ok": False, "error": f"pass {k}: no marker in the frame at rest"}
            wait(conv.set_speed(v), 10.0)
            seen = 0
            for _ in range(MAX_FRAMES):
                time.sleep(FRAME_GAP_S)
                c, m = shot()
                if m is None:
                    if seen:
                        break                             # it has left the view
                    continue
                seen += 1
                travelled = diff(c, c0, cell.encoder.conveyor_bits) / cpm
                rows.append((travelled, v, (m[0] - m0[0]) - travelled))
                moves.append((m[0] - m0[0], m[1] - m0[1]))
            wait(conv.stop(), 10.0)
            ask(f"marker.{k}.off", "Take the marker off the belt, then press Enter")
            if seen < 2:
                return {"ok": False, "error": f"pass {k}: the marker was seen in {seen} moving "
                                              "frames (it must cross the view)"}
    finally:
        try:
            wait(conv.stop(), 10.0)
        finally:
            ctl.close()
    a = np.array([[r[0], r[1]] for r in rows])
    b = np.array([r[2] for r in rows])
    (scale, delay_s), *_ = np.linalg.lstsq(a, b, rcond=None)
    fit_rms = float(np.sqrt(np.mean((a @ np.array([scale, delay_s]) - b) ** 2)))
    delay_ms = 1000.0 * float(delay_s)
    found = {"ok": abs(delay_ms) <= opts.timing_limit_ms, "delay_ms": round(delay_ms, 2),
             "delay_mm": round(float(delay_s) * max(speeds), 3), "at_mm_s": max(speeds),
             "limit_ms": opts.timing_limit_ms, "frames": len(rows),
             "scale_error_pct": round(100.0 * float(scale), 3), "fit_rms_mm": round(fit_rms, 3)}
    found.update(_travel(cell, calibration, moves, centre_mm))
    if not found["travel_ok"]:
        found["ok"] = False
    return found


def _travel(cell: CellSpec, calibration: CameraCalibration, moves: list[tuple[float, float]],
            centre_mm: tuple[float, float] | None) -> dict[str, Any]:
    """The belt's travel as the camera's calibration sees it: the cell frame's x must be
    the travel. Over ``TRAVEL_LIMIT_DEG`` (a target laid turned) the step says so and gives
    the calibration turned square to the travel about the target's centre (the one point
    the person placed for sure), to use instead or to check by laying the target again."""
    deg = travel_deg(moves)
    out: dict[str, Any] = {"travel_deg": round(deg, 3), "travel_limit_deg": TRAVEL_LIMIT_DEG,
                           "travel_ok": abs(deg) <= TRAVEL_LIMIT_DEG}
    if out["travel_ok"]:
        return out
    if centre_mm is None:
        mid = centred_pose(calibration, cell.camera.width_px, cell.camera.height_px)
        centre_mm = (mid.x_mm, mid.y_mm)
    square = turned_about(calibration, centre_mm, -deg)
    out["calibration_square_to_travel"] = {
        "origin_mm": [round(v, 5) for v in square.origin_mm],
        "mm_per_px": round(square.mm_per_px, 8), "rotation_deg": round(square.rotation_deg, 5),
        **({"homography": [float(f"{v:.12g}") for v in square.homography]}
           if square.homography is not None else {})}
    out["error"] = (f"the belt travels {deg:.2f} deg off the camera's x axis (over "
                    f"{TRAVEL_LIMIT_DEG:g} deg): the calibration target was laid turned, so "
                    "parts drift across the belt as they are tracked. Use "
                    "calibration_square_to_travel (turned about the target's centre), or lay "
                    "the target square to the travel and calibrate again")
    return out
