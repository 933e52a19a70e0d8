"""``feeder calibrate camera|belt|tool CELL``: the guided calibrations (thesis 8.2.1.7).

On the simulated cell (``hal: sim``) each command runs its procedure against the
simulator: it lays a target under the camera, or moves the robot onto a marker with a
little touch noise (fixed ``--seed``). The ``--sim-*`` options set the simulator's hidden
truth (a camera that is not where the cell file says, a belt encoder that is not quite
``counts_per_mm``, a tool offset) so the procedure can be seen to recover it. With
``--hal emulated`` (or on a cell whose ``hal`` is ``emulated`` or ``real``) the belt and tool
procedures run through the Galil and V+ drivers (``calibration.drivers``): against the
emulators a scripted operator touches the marker; on a real cell the operator jogs the
robot with the pendant and presses Enter. ``calibrate camera --image`` works on any cell
from saved images of the target.

The target is the cell's ``camera.target`` unless ``--target``/``--board``/``--square`` (and
``--dot``, ``--marker``, ``--dictionary``) say otherwise; ``--no-prior`` trusts the stated
``--pose`` alone (a first calibration, or one far off); several ``--image`` (or, on the
simulated cell, ``--views``) also give the full lens model (``calibration.camera_model``);
``--json`` prints one JSON object; a result over the cell's limits is refused (exit 3,
nothing written) unless ``--force``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import json
import math
import os
from pathlib import Path

import cv2
import numpy as np

from feeder_bt.calibration import (
    DEFAULT_TARGETS,
    BeltFit,
    CameraFit,
    ToolFit,
    belt_procedure,
    camera_procedure,
    sim_waiter,
    tool_procedure,
    window_error_mm,
)
from feeder_bt.calibration.belt import TRAVEL_LIMIT_DEG, travel_in_cell_deg
from feeder_bt.calibration.camera import Target, TargetPose, calibration_values, centred_pose
from feeder_bt.calibration.camera_model import (
    DEFAULT_MAX_BELT_MM,
    DEFAULT_MAX_RMS_PX,
    CameraResult,
    calibrate_camera_views,
)
from feeder_bt.calibration.drivers import OperatorTouch, PlantToucher, real_waiter, refresh
from feeder_bt.calibration.files import calibration_path, write_calibration_file
from feeder_bt.calibration.procedure import CalibrationError
from feeder_bt.calibration.targets import parse_board
from feeder_bt.cli.argtypes import expect_kind
from feeder_bt.config import load_cell
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import FeederError
from feeder_bt.core.jobs import Job
from feeder_bt.core.model import CameraCalibration, CellSpec, Scenario, VisionRecipe

BELT_MARKER_MM = (800.0, 305.0)      # in reach of the robot, steps of 80 mm stay in reach
TOOL_POINT_MM = (1150.0, 305.0)      # a fixed point (fixture) in the robot's reach


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("calibrate", help="guided calibrations: camera, belt, tool")
    sub = p.add_subparsers(dest="what", required=True, metavar="WHAT",
                           parser_class=type(p))

    def common(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("cell", help="cell description YAML, e.g. cells/sim.yaml")
        sp.add_argument("--seed", type=int, default=1,
                        help="simulated cell: seed of image noise and touch noise (default 1)")
        sp.add_argument("--write", nargs="?", const="", metavar="FILE",
                        help="write the result as YAML to FILE (camera: default the cell's "
                             "camera.calibration_file)")

    c = sub.add_parser("camera", help="camera <-> belt frame from an image of a target")
    common(c)
    c.add_argument("--target", choices=sorted(DEFAULT_TARGETS),
                   help="target kind (default: the cell's camera.target, else chessboard); "
                        "defaults: " + "; ".join(f"{k} {t.nx}x{t.ny} {t.pitch_mm:g} mm"
                                                 for k, t in DEFAULT_TARGETS.items()))
    c.add_argument("--board", metavar="NXxNY",
                   help="points per row and rows (chessboard/charuco: inner corners)")
    c.add_argument("--square", "--pitch", dest="square", type=float, metavar="MM",
                   help="square side (circle grids: dot spacing along a row), mm")
    c.add_argument("--dot", type=float, metavar="MM", help="circle grids: dot diameter, mm")
    c.add_argument("--marker", type=float, metavar="MM", help="charuco: marker side, mm")
    c.add_argument("--dictionary", metavar="NAME", help="charuco: ArUco dictionary, e.g. "
                   "DICT_4X4_250")
    c.add_argument("--no-prior", action="store_true",
                   help="a first calibration: do not use the cell's present calibration to "
                        "tell the board's corners apart (the stated --pose is trusted)")
    c.add_argument("--pose", nargs=3, type=float, metavar=("X", "Y", "DEG"),
                   help="target centre (belt mm) and angle; default: centred in the window")
    c.add_argument("--image", action="append", metavar="FILE",
                   help="use this saved image of the target instead of the camera; repeat "
                        "for lens distortion (the first is the one at --pose)")
    c.add_argument("--save-image", metavar="FILE",
                   help="simulated cell: also save the rendered image of the target (a test "
                        "board for --image)")
    c.add_argument("--sim-truth", nargs=4, type=float, default=[0, 0, 0, 0],
                   metavar=("DX", "DY", "DEG", "PCT"),
                   help="simulated camera's error: origin shift mm, rotation, scale %%")
    c.add_argument("--views", type=int, default=0, metavar="N",
                   help="simulated cell: also N views of the target held turned and tilted, "
                        "for the lens (default: 12 when the simulated lens bends, else 0)")
    c.add_argument("--lens-model", choices=("auto", "standard", "rational"), default="auto",
                   help="distortion model with several views: k1,k2,p1,p2,k3 (standard), "
                        "and k4..k6 (rational, wide lenses) or whichever fits (auto)")
    c.add_argument("--max-rms-px", type=float, metavar="PX",
                   help="refuse a lens model over this reprojection rms (default: the "
                        "cell's camera.target.max_rms_px, else 1.0)")
    c.add_argument("--max-belt-mm", type=float, metavar="MM",
                   help="refuse a belt plane over this rms (default: the cell's "
                        "camera.target.max_belt_mm, else 0.3)")
    c.add_argument("--force", action="store_true",
                   help="write (and exit 0) even when the result is over the limits")
    c.add_argument("--json", action="store_true",
                   help="print one JSON object (fx, fy, cx, cy, dist, rms_px, views_used, "
                        "views_rejected, belt_rms_mm, ...) instead of the report")

    def hal_option(sp: argparse.ArgumentParser) -> None:
        sp.add_argument("--hal", choices=("sim", "emulated", "real"),
                        help="run through the simulator (sim), the drivers against the "
                             "emulators (emulated) or the real cell's drivers (real); "
                             "default: the cell's `hal`")

    b = sub.add_parser("belt", help="belt <-> robot: counts per mm and belt direction")
    common(b)
    hal_option(b)
    b.add_argument("--noise", type=float, default=0.05, help="touch noise sigma, mm")
    b.add_argument("--sim-counts-per-mm", type=float,
                   help="simulated encoder's true counts per mm (default: the cell's)")
    b.add_argument("--sim-frame-deg", type=float, default=0.0,
                   help="simulated robot frame's angle from the belt frame")

    t = sub.add_parser("tool", help="tool offset from touches of one point at several angles")
    common(t)
    hal_option(t)
    t.add_argument("--noise", type=float, default=0.05, help="touch noise sigma, mm")
    t.add_argument("--sim-tool", nargs=2, type=float, default=[0.0, 0.0],
                   metavar=("DX", "DY"), help="simulated tool's true offset, mm")
    p.set_defaults(handler=cmd_calibrate)
    return p


def cmd_calibrate(args: argparse.Namespace) -> int:
    expect_kind(args.cell, "cell", "", "give the cell description it runs on (its `cell:` key names it)")
    cell = load_cell(args.cell, calibration_files=False)   # we may be about to write them
    if args.what == "camera":
        return _camera(args, cell)
    kind = args.hal or cell.hal
    if args.what == "belt":
        if kind == "sim":
            fit = sim_belt(cell, seed=args.seed, noise_mm=args.noise,
                           counts_per_mm=args.sim_counts_per_mm, frame_deg=args.sim_frame_deg)
        else:
            fit = driver_belt(cell, kind, seed=args.seed, noise_mm=args.noise)
        print(format_belt(fit, cell.robot.base_deg))
        _write(args, cell, "belt", {**fit.as_dict(), **belt_travel(fit, cell.robot.base_deg)})
    else:
        if kind == "sim":
            fit_t = sim_tool(cell, tuple(args.sim_tool), seed=args.seed, noise_mm=args.noise)
        else:
            fit_t = driver_tool(cell, kind, tuple(args.sim_tool), seed=args.seed,
                                noise_mm=args.noise)
        print(format_tool(fit_t))
        _write(args, cell, "tool", fit_t.as_dict())
    return 0


class HardwareNeeded(FeederError):
    """The procedure needs what this cell does not offer (a simulated camera to render)."""

    exit_code = 2


def _need_sim(cell: CellSpec, what: str) -> None:
    if cell.hal != "sim":
        raise HardwareNeeded(f"calibrate {what}: cell {cell.name!r} has hal {cell.hal!r}: "
                             "photograph the target lying on the belt and give the photo "
                             "with --image (and its place with --pose)")


def camera_target(cell: CellSpec, args: argparse.Namespace) -> Target:
    """The target: the flags over the cell's ``camera.target`` over the kind's default."""
    spec = cell.camera.target
    kind = args.target or (spec.kind if spec else "chessboard")
    if spec is not None and kind == spec.kind:
        t = Target(spec.kind, spec.board[0], spec.board[1], spec.pitch_mm, spec.dot_mm,
                   spec.marker_mm, spec.dictionary)
    else:
        t = DEFAULT_TARGETS[kind]
    nx, ny = parse_board(args.board) if args.board else (t.nx, t.ny)
    changes = {"nx": nx, "ny": ny}
    for flag, field in (("square", "pitch_mm"), ("dot", "dot_mm"), ("marker", "marker_mm"),
                        ("dictionary", "dictionary")):
        if getattr(args, flag) is not None:
            changes[field] = getattr(args, flag)
    if args.square is not None and args.dot is None and kind != "charuco" \
            and t.dot_mm >= 0.8 * args.square:
        changes["dot_mm"] = 0.4 * args.square            # a default dot that fits
    if args.square is not None and args.marker is None and kind == "charuco":
        changes["marker_mm"] = 0.0                       # the default share of the square
    return dataclasses.replace(t, **changes)


def _read(path: str):
    img = cv2.imread(path, cv2.IMREAD_GRAYSCALE) if Path(path).is_file() else None
    if img is None:                             # (imread would warn on stderr)
        raise CalibrationError(f"{path}: cannot read the image (PNG, JPG or BMP)")
    return img


class CalibrationRefused(FeederError):
    """The calibration was computed but is over the cell's limits: nothing was written."""

    exit_code = 3


def camera_limits(cell: CellSpec, args: argparse.Namespace) -> tuple[float, float]:
    """(max reprojection rms px, max belt rms mm): the flags over the cell's target."""
    spec = cell.camera.target
    px = args.max_rms_px if args.max_rms_px is not None else (
        spec.max_rms_px if spec else DEFAULT_MAX_RMS_PX)
    mm = args.max_belt_mm if args.max_belt_mm is not None else (
        spec.max_belt_mm if spec else DEFAULT_MAX_BELT_MM)
    for flag, v in (("--max-rms-px", px), ("--max-belt-mm", mm)):
        if not v > 0:
            raise CalibrationError(f"{flag} must be > 0, got {v:g}")
    return px, mm


def _camera(args: argparse.Namespace, cell: CellSpec) -> int:
    target = camera_target(cell, args)
    cam = cell.camera
    pose = TargetPose(*args.pose) if args.pose else centred_pose(cam.calibration, cam.width_px,
                                                                 cam.height_px)
    limits = camera_limits(cell, args)
    truth = None
    prior = not args.no_prior
    if args.image:
        images = [(p, _read(p)) for p in args.image]
    else:
        _need_sim(cell, "camera")
        base = true_camera(cell)                    # the simulated camera's real mapping
        truth = sim_truth(base, *args.sim_truth)
        from feeder_bt.sim.target import SIM_LENS_VIEWS

        n = args.views if args.views else (SIM_LENS_VIEWS if truth.intrinsics else 0)
        images = sim_images(cell, target, pose, truth, seed=args.seed, views=n,
                            save=args.save_image)
    result = calibrate_camera_views(images, target, pose, cam.calibration, prior,
                                    args.lens_model)
    refused = result.refusal(*limits)
    if args.json:
        d = result.as_dict()
        d["target"] = target.describe()
        d["pose"] = [pose.x_mm, pose.y_mm, pose.angle_deg]
        if truth is not None:
            d["sim_window_error_mm"] = round(window_error_mm(
                result.calibration, truth, cam.width_px, cam.height_px), 5)
        d["refused"] = refused
        print(json.dumps(d))
    else:
        print(f"target: {target.describe()} at x {pose.x_mm:g}, y {pose.y_mm:g} mm, "
              f"{pose.angle_deg:g} deg")
        print(format_result(result, cell, truth))
    if refused and not args.force:
        raise CalibrationRefused(f"calibrate camera: refused, nothing written: {refused}")
    values = calibration_values(result.calibration)
    values["residual_mm"] = {"rms": round(result.belt.rms_mm, 4),
                             "max": round(result.belt.max_mm, 4)}
    values["record"] = {k: v for k, v in result.as_dict().items() if k != "calibration"}
    _write(args, cell, "camera", values, default=calibration_path(cell),
           quiet=args.json)
    return 0


def _write(args: argparse.Namespace, cell: CellSpec, what: str, values: dict,
           default: Path | None = None, quiet: bool = False) -> None:
    if args.write is None:
        return
    dest = Path(args.write) if args.write else default
    if dest is None:
        raise CalibrationError(f"--write needs a FILE: cell {cell.name!r} names no "
                               "camera.calibration_file")
    stamp = datetime.datetime.now().isoformat(timespec="seconds")
    header = (f"feeder calibrate {what} {args.cell} (seed {args.seed}), {stamp}\n"
              + {"camera": "Name this file as camera.calibration_file in the cell description.",
                 "belt": "Copy counts_per_mm into encoder.counts_per_mm of the cell.",
                 "tool": "Copy tool_offset_mm into the scenario's parts.*.tool_offset."}[what])
    written = write_calibration_file(dest, values, header)
    if quiet:
        return
    print(f"wrote {written}")
    if what == "camera" and dest != default:    # a path in a file is relative to that file
        rel = os.path.relpath(dest.resolve(), Path(cell.path).resolve().parent)
        print(f"to use it, name it in {cell.path}:  camera: {{calibration_file: {rel}}}")


# ------------------------------------------------------------------------------ simulator


def sim_images(cell: CellSpec, target: Target, pose: TargetPose, truth: CameraCalibration,
               seed: int = 1, views: int = 0, save: str | None = None
               ) -> list[tuple[str, np.ndarray]]:
    """The simulated camera's images of the target (``hal.sim.target.sim_images``)."""
    from feeder_bt.sim.target import sim_images as images

    return images(cell, target, pose, truth, seed, views, save)


def true_camera(cell: CellSpec) -> CameraCalibration:
    """How the simulated camera really maps (``hal.sim.imperfect.true_calibration`` without
    the residual error a calibration leaves: the camera, lens and tilt a calibration finds)."""
    from feeder_bt.sim.imperfect import true_calibration

    return true_calibration(cell, residual=False)


def sim_truth(nominal: CameraCalibration, dx: float = 0.0, dy: float = 0.0,
              deg: float = 0.0, scale_pct: float = 0.0) -> CameraCalibration:
    """The cell's calibration with an error added: how the simulated camera really maps
    (a full calibration's homography gets the same error in the belt frame)."""
    from feeder_bt.vision.pixels import shifted

    return shifted(nominal, (dx, dy), scale_pct, deg)


def sim_camera(cell: CellSpec, target, pose: TargetPose,
               truth: CameraCalibration | None = None, seed: int = 1,
               prior: bool = True, save: str | None = None) -> CameraFit:
    """Calibrate the simulated camera (really mapping by ``truth``) from a target at ``pose``
    (``save``: also write the image it grabbed to this file)."""
    from feeder_bt.sim.target import TargetCamera

    camera = TargetCamera(cell.camera, truth, seed=seed)
    camera.place(target, pose)
    if save:
        from feeder_bt.core.images import write_image
        write_image(save, camera.grab().result.image)
        camera.frames = 0                       # the procedure grabs the same image again
    return camera_procedure(camera, lambda job: job.result if job.ok else _raise(job),
                            target, pose, cell.camera.calibration, prior)


def _raise(job):
    raise job.error


def _sim_cell(cell: CellSpec, seed: int, counts_per_mm: float | None = None):
    from feeder_bt.sim.devices import make_sim_hal

    if counts_per_mm is not None:
        if not counts_per_mm > 0:
            raise CalibrationError(f"--sim-counts-per-mm must be > 0, got {counts_per_mm:g}")
        # the simulated belt truly gives this many counts per mm: no scale error on top
        cell = dataclasses.replace(cell, encoder=dataclasses.replace(
            cell.encoder, counts_per_mm=counts_per_mm), sim=dataclasses.replace(
            cell.sim, encoder_scale_pct=0.0))
    empty = Scenario(name="calibration", path=Path("-"), cell_path=Path(cell.path), parts={},
                     hopper={}, vision=VisionRecipe())
    clock = SimClock()
    hal = make_sim_hal(empty, cell, clock, seed)
    return hal, sim_waiter(hal, clock)


def sim_belt(cell: CellSpec, seed: int = 1, noise_mm: float = 0.05,
             counts_per_mm: float | None = None, frame_deg: float = 0.0) -> BeltFit:
    """Belt calibration on the simulated cell: a marker at ``BELT_MARKER_MM``, 5 touches."""
    from feeder_bt.sim.target import RobotFrameView, SimToucher

    hal, wait = _sim_cell(cell, seed, counts_per_mm)
    try:
        view = RobotFrameView(hal.world, frame_deg)
        hal.robot_position = view
        rig = SimToucher(hal.world, hal.robot, noise_mm=noise_mm, seed=seed, view=view)
        rig.put_marker(*BELT_MARKER_MM)
        return belt_procedure(hal, wait, rig.touch_marker, robot_bits=cell.encoder.robot_bits)
    finally:
        hal.close()


def sim_tool(cell: CellSpec, tool_offset_mm: tuple[float, float] = (0.0, 0.0), seed: int = 1,
             noise_mm: float = 0.05, angles_deg=(-90.0, -30.0, 30.0, 90.0)) -> ToolFit:
    """Tool calibration on the simulated cell: a fixed point touched at ``angles_deg``."""
    from feeder_bt.sim.target import SimToucher

    hal, wait = _sim_cell(cell, seed)
    try:
        rig = SimToucher(hal.world, hal.robot, tool_offset_mm, noise_mm=noise_mm, seed=seed)
        point = TOOL_POINT_MM
        return tool_procedure(hal, wait, lambda rz: rig.touch(point, rz), angles_deg)
    finally:
        hal.close()


# ------------------------------------------------------------------------------ drivers


def _driver_hal(cell: CellSpec, kind: str, seed: int):
    """The cell behind its drivers: the emulators (``emulated``) or the real controllers."""
    from feeder_bt.app.factory import make_hal

    empty = Scenario(name="calibration", path=Path("-"), cell_path=Path(cell.path), parts={},
                     hopper={}, vision=VisionRecipe())
    hal, _ = make_hal(kind, empty, cell, seed)
    return hal


def driver_belt(cell: CellSpec, kind: str, seed: int = 1, noise_mm: float = 0.05,
                ask=input, operator: bool | None = None) -> BeltFit:
    """Belt calibration through the drivers (see ``calibration.drivers``); ``operator``: an
    operator at the terminal touches (default: on a real cell), else the emulated plant's
    scripted one."""
    hal = _driver_hal(cell, kind, seed)
    try:
        if not (kind == "real" if operator is None else operator):
            rig = PlantToucher(hal.extras["plant"], hal.robot, noise_mm=noise_mm, seed=seed)
            rig.put_marker(*BELT_MARKER_MM)
            touch = rig.touch_marker
        else:
            print("Stick a marker on the belt within the robot's reach. At each prompt jog "
                  "the tool tip onto the marker with the pendant; the belt then advances "
                  "80 mm and the robot goes to its safe pose.")
            def touch() -> Job:
                return OperatorTouch("tool tip on the marker? press Enter ", ask)
        return belt_procedure(hal, real_waiter(), touch, robot_bits=cell.encoder.robot_bits,
                              settle=refresh(hal))
    finally:
        hal.close()


def driver_tool(cell: CellSpec, kind: str, tool_offset_mm: tuple[float, float] = (0.0, 0.0),
                seed: int = 1, noise_mm: float = 0.05, ask=input,
                angles_deg=(-90.0, -30.0, 30.0, 90.0), operator: bool | None = None
                ) -> ToolFit:
    """Tool calibration through the drivers (see ``calibration.drivers``; ``operator`` as
    for ``driver_belt``)."""
    hal = _driver_hal(cell, kind, seed)
    try:
        if not (kind == "real" if operator is None else operator):
            rig = PlantToucher(hal.extras["plant"], hal.robot, tool_offset_mm,
                               noise_mm=noise_mm, seed=seed)
            def touch(rz: float) -> Job:
                return rig.touch(np.array(TOOL_POINT_MM), rz)
        else:
            print("Fix a pointed marker within the robot's reach. At each prompt jog the "
                  "tool tip onto it with the tool turned to the angle asked.")
            def touch(rz: float) -> Job:
                return OperatorTouch(f"tool turned {rz:g} deg, tip on the point? press Enter ",
                                     ask)
        return tool_procedure(hal, real_waiter(), touch, angles_deg, settle=refresh(hal))
    finally:
        hal.close()


# ------------------------------------------------------------------------------ output


def format_camera(fit: CameraFit, cell: CellSpec, truth: CameraCalibration | None) -> str:
    c = fit.calibration
    lines = [f"camera: origin_mm [{c.origin_mm[0]:.3f}, {c.origin_mm[1]:.3f}], mm_per_px "
             f"{c.mm_per_px:.6f}, rotation_deg {c.rotation_deg:.4f}",
             f"  residual over {fit.n_points} points: rms {fit.rms_mm:.3f} mm, max "
             f"{fit.max_mm:.3f} mm (affine {fit.affine_rms_mm:.3f}, homography "
             f"{fit.homography_rms_mm:.3f} mm rms)"]
    lines += _window_lines(c, cell, truth)
    if fit.hint:
        lines.append(f"  hint: {fit.hint}")
    return "\n".join(lines)


def _window_lines(c: CameraCalibration, cell: CellSpec, truth: CameraCalibration | None
                  ) -> list[str]:
    """How far a new calibration moves the camera window from the cell's present one, and
    (simulated cell) from the simulated camera's truth."""
    cam = cell.camera
    lines = [f"  moves the window by up to "
             f"{window_error_mm(c, cam.calibration, cam.width_px, cam.height_px):.2f} mm "
             "from the cell's present calibration"]
    if truth is not None:
        err = window_error_mm(c, truth, cam.width_px, cam.height_px)
        lines.append(f"  simulator check: up to {err:.3f} mm from the simulated camera's truth "
                     "over the window")
    return lines


def format_result(r: CameraResult, cell: CellSpec, truth: CameraCalibration | None) -> str:
    c = r.calibration
    lines = []
    if r.lens is not None:
        m = r.lens
        sd = m.std
        lines.append(f"lens ({'rational' if m.rational else 'standard'} model) from "
                     f"{len(m.used)} views: fx {m.fx:.2f} ± {sd.get('fx', 0):.2f}, fy "
                     f"{m.fy:.2f} ± {sd.get('fy', 0):.2f}, cx {m.cx:.2f} ± "
                     f"{sd.get('cx', 0):.2f}, cy {m.cy:.2f} ± {sd.get('cy', 0):.2f} px")
        lines.append("  dist " + ", ".join(f"{n} {v:.5f}" for n, v in zip(
            ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"), m.dist, strict=False)))
        worst = max(m.per_view.items(), key=lambda kv: kv[1])
        lines.append(f"  reprojection rms {m.rms_px:.3f} px (worst view {worst[0]} "
                     f"{worst[1]:.3f} px)")
    for name, why in r.views_rejected:
        lines.append(f"  view {name} not used: {why}")
    lines.append(f"belt plane over {r.belt.n_points} points of view {r.first}: rms "
                 f"{r.belt.rms_mm:.3f} mm, max {r.belt.max_mm:.3f} mm (a similarity would "
                 f"leave {r.belt.similarity_rms_mm:.3f} mm)")
    lines.append(f"  near the centre: mm_per_px {c.mm_per_px:.6f}, rotation_deg "
                 f"{c.rotation_deg:.4f}, origin_mm [{c.origin_mm[0]:.3f}, "
                 f"{c.origin_mm[1]:.3f}]")
    lines += _window_lines(c, cell, truth)
    if r.note:
        lines.append(f"  note: {r.note}")
    return "\n".join(lines)


def belt_travel(fit: BeltFit, base_deg: float) -> dict[str, float]:
    """The travel in the cell frame and the ``robot.base_deg`` that puts it along x."""
    return {"travel_in_cell_deg": round(travel_in_cell_deg(fit, base_deg), 4),
            "base_deg_square_to_travel": round(-fit.direction_deg, 4)}


def format_belt(fit: BeltFit, base_deg: float = 0.0) -> str:
    off = travel_in_cell_deg(fit, base_deg)
    lines = [f"belt: counts_per_mm {fit.counts_per_mm:.4f}, direction {fit.direction_deg:.3f} "
             f"deg in the robot frame ({fit.direction[0]:.6f}, {fit.direction[1]:.6f})",
             f"  residual over {fit.n_touches} touches, {fit.travel_mm:.0f} mm of travel: rms "
             f"{fit.rms_mm:.3f} mm, max {fit.max_mm:.3f} mm"]
    if abs(off) > TRAVEL_LIMIT_DEG:
        lines.append(f"  the belt travels {off:.3f} deg off the cell frame's x axis (over "
                     f"{TRAVEL_LIMIT_DEG:g} deg; robot.base_deg {base_deg:g}): picks drift "
                     f"across the belt {abs(math.sin(math.radians(off))) * 600:.1f} mm per 600 "
                     f"mm tracked. Set robot.base_deg: {-fit.direction_deg:.3f} (or teach the "
                     "frame again with marks square to the travel)")
    else:
        lines.append(f"  the belt travels {off:.3f} deg off the cell frame's x axis (within "
                     f"{TRAVEL_LIMIT_DEG:g} deg)")
    return "\n".join(lines)


def format_tool(fit: ToolFit) -> str:
    return (f"tool: offset [{fit.offset_mm[0]:.3f}, {fit.offset_mm[1]:.3f}] mm (flange frame), "
            f"point touched [{fit.point_mm[0]:.2f}, {fit.point_mm[1]:.2f}] mm\n"
            f"  residual over {fit.n_touches} touches: rms {fit.rms_mm:.3f} mm, max "
            f"{fit.max_mm:.3f} mm")
