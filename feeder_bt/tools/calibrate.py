"""``feeder calibrate camera|belt|tool CELL``: the guided calibrations (thesis 8.2.1.7).

On the simulated cell (``hal: sim``) each command runs its procedure against the
simulator: it lays a target under the camera, or moves the robot onto a marker with a
little touch noise (fixed ``--seed``). The ``--sim-*`` options set the simulator's hidden
truth (a camera that is not where the cell file says, a belt encoder that is not quite
``counts_per_mm``, a tool offset) so the procedure can be seen to recover it. On other
cells the procedures need the hardware drivers, which this release does not have;
``calibrate camera --image`` works on any cell from a saved image of the target.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import os
from pathlib import Path

import cv2

from ..calibration import (
    DEFAULT_TARGETS,
    BeltFit,
    CameraFit,
    ToolFit,
    belt_procedure,
    calibrate_camera_image,
    camera_procedure,
    sim_waiter,
    tool_procedure,
    window_error_mm,
)
from ..calibration.camera import TargetPose, centred_pose
from ..calibration.common import CalibrationError
from ..calibration.files import calibration_path, write_calibration_file
from ..clock import SimClock
from ..errors import FeederError
from ..scenario import load_cell
from ..scenario.model import CameraCalibration, CellSpec, Scenario, VisionRecipe

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
    c.add_argument("--target", default="chessboard", choices=sorted(DEFAULT_TARGETS),
                   help="chessboard (8x12 inner corners, 40 mm) or dots (9x13, 36 mm)")
    c.add_argument("--pose", nargs=3, type=float, metavar=("X", "Y", "DEG"),
                   help="target centre (belt mm) and angle; default: centred in the window")
    c.add_argument("--image", help="use this saved image of the target instead of the camera")
    c.add_argument("--sim-truth", nargs=4, type=float, default=[0, 0, 0, 0],
                   metavar=("DX", "DY", "DEG", "PCT"),
                   help="simulated camera's error: origin shift mm, rotation, scale %%")

    b = sub.add_parser("belt", help="belt <-> robot: counts per mm and belt direction")
    common(b)
    b.add_argument("--noise", type=float, default=0.05, help="touch noise sigma, mm")
    b.add_argument("--sim-counts-per-mm", type=float,
                   help="simulated encoder's true counts per mm (default: the cell's)")
    b.add_argument("--sim-frame-deg", type=float, default=0.0,
                   help="simulated robot frame's angle from the belt frame")

    t = sub.add_parser("tool", help="tool offset from touches of one point at several angles")
    common(t)
    t.add_argument("--noise", type=float, default=0.05, help="touch noise sigma, mm")
    t.add_argument("--sim-tool", nargs=2, type=float, default=[0.0, 0.0],
                   metavar=("DX", "DY"), help="simulated tool's true offset, mm")
    p.set_defaults(handler=cmd_calibrate)
    return p


def cmd_calibrate(args: argparse.Namespace) -> int:
    cell = load_cell(args.cell, calibration_files=False)   # we may be about to write them
    if args.what == "camera":
        return _camera(args, cell)
    _need_sim(cell, args.what)
    if args.what == "belt":
        fit = sim_belt(cell, seed=args.seed, noise_mm=args.noise,
                       counts_per_mm=args.sim_counts_per_mm, frame_deg=args.sim_frame_deg)
        print(format_belt(fit))
        _write(args, cell, "belt", fit.as_dict())
    else:
        fit_t = sim_tool(cell, tuple(args.sim_tool), seed=args.seed, noise_mm=args.noise)
        print(format_tool(fit_t))
        _write(args, cell, "tool", fit_t.as_dict())
    return 0


class HardwareNeeded(FeederError):
    """The procedure has to move real hardware, and this cell's drivers are not there yet."""

    exit_code = 2


def _need_sim(cell: CellSpec, what: str) -> None:
    if cell.hal != "sim":
        raise HardwareNeeded(f"calibrate {what}: cell {cell.name!r} has hal {cell.hal!r}: the "
                             "real-cell procedure needs the hardware drivers (not yet in this "
                             "release)")


def _camera(args: argparse.Namespace, cell: CellSpec) -> int:
    target = DEFAULT_TARGETS[args.target]
    cam = cell.camera
    pose = TargetPose(*args.pose) if args.pose else centred_pose(cam.calibration, cam.width_px,
                                                                 cam.height_px)
    truth = None
    if args.image:
        img = (cv2.imread(args.image, cv2.IMREAD_GRAYSCALE) if Path(args.image).is_file()
               else None)                       # imread would warn on stderr
        if img is None:
            raise CalibrationError(f"{args.image}: cannot read the image (PNG, JPG or BMP)")
        fit = calibrate_camera_image(img, target, pose, cam.calibration)
    else:
        _need_sim(cell, "camera")
        base = cam.sim_truth or cam.calibration     # the simulated camera's real pose
        truth = sim_truth(base, *args.sim_truth)
        fit = sim_camera(cell, target, pose, truth, seed=args.seed)
    print(format_camera(fit, cell, truth))
    _write(args, cell, "camera", fit.as_dict(), default=calibration_path(cell))
    return 0


def _write(args: argparse.Namespace, cell: CellSpec, what: str, values: dict,
           default: Path | None = None) -> None:
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
    print(f"wrote {write_calibration_file(dest, values, header)}")
    if what == "camera" and dest != default:    # a path in a file is relative to that file
        rel = os.path.relpath(dest.resolve(), Path(cell.path).resolve().parent)
        print(f"to use it, name it in {cell.path}:  camera: {{calibration_file: {rel}}}")


# ------------------------------------------------------------------------------ simulator


def sim_truth(nominal: CameraCalibration, dx: float = 0.0, dy: float = 0.0,
              deg: float = 0.0, scale_pct: float = 0.0) -> CameraCalibration:
    """The cell's calibration with an error added: how the simulated camera really maps."""
    return CameraCalibration(origin_mm=(nominal.origin_mm[0] + dx, nominal.origin_mm[1] + dy),
                             mm_per_px=nominal.mm_per_px * (1.0 + scale_pct / 100.0),
                             rotation_deg=nominal.rotation_deg + deg)


def sim_camera(cell: CellSpec, target, pose: TargetPose,
               truth: CameraCalibration | None = None, seed: int = 1) -> CameraFit:
    """Calibrate the simulated camera (really mapping by ``truth``) from a target at ``pose``."""
    from ..hal.sim.target import TargetCamera

    camera = TargetCamera(cell.camera, truth, seed=seed)
    camera.place(target, pose)
    return camera_procedure(camera, lambda job: job.result if job.ok else _raise(job),
                            target, pose, cell.camera.calibration)


def _raise(job):
    raise job.error


def _sim_cell(cell: CellSpec, seed: int, counts_per_mm: float | None = None):
    from ..hal.sim.devices import make_sim_hal

    if counts_per_mm is not None:
        if not counts_per_mm > 0:
            raise CalibrationError(f"--sim-counts-per-mm must be > 0, got {counts_per_mm:g}")
        cell = dataclasses.replace(cell, encoder=dataclasses.replace(
            cell.encoder, counts_per_mm=counts_per_mm))
    empty = Scenario(name="calibration", path=Path("-"), cell_path=Path(cell.path), parts={},
                     hopper={}, vision=VisionRecipe())
    clock = SimClock()
    hal = make_sim_hal(empty, cell, clock, seed)
    return hal, sim_waiter(hal, clock)


def sim_belt(cell: CellSpec, seed: int = 1, noise_mm: float = 0.05,
             counts_per_mm: float | None = None, frame_deg: float = 0.0) -> BeltFit:
    """Belt calibration on the simulated cell: a marker at ``BELT_MARKER_MM``, 5 touches."""
    from ..hal.sim.target import RobotFrameView, SimToucher

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
    from ..hal.sim.target import SimToucher

    hal, wait = _sim_cell(cell, seed)
    try:
        rig = SimToucher(hal.world, hal.robot, tool_offset_mm, noise_mm=noise_mm, seed=seed)
        point = TOOL_POINT_MM
        return tool_procedure(hal, wait, lambda rz: rig.touch(point, rz), angles_deg)
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
    cam = cell.camera
    lines.append(f"  moves the window by up to {window_error_mm(c, cam.calibration, cam.width_px, cam.height_px):.2f} mm "
                 "from the cell's present calibration")
    if truth is not None:
        err = window_error_mm(c, truth, cam.width_px, cam.height_px)
        lines.append(f"  simulator check: up to {err:.3f} mm from the simulated camera's truth "
                     "over the window")
    if fit.hint:
        lines.append(f"  hint: {fit.hint}")
    return "\n".join(lines)


def format_belt(fit: BeltFit) -> str:
    return (f"belt: counts_per_mm {fit.counts_per_mm:.4f}, direction {fit.direction_deg:.3f} "
            f"deg in the robot frame ({fit.direction[0]:.6f}, {fit.direction[1]:.6f})\n"
            f"  residual over {fit.n_touches} touches, {fit.travel_mm:.0f} mm of travel: rms "
            f"{fit.rms_mm:.3f} mm, max {fit.max_mm:.3f} mm")


def format_tool(fit: ToolFit) -> str:
    return (f"tool: offset [{fit.offset_mm[0]:.3f}, {fit.offset_mm[1]:.3f}] mm (flange frame), "
            f"point touched [{fit.point_mm[0]:.2f}, {fit.point_mm[1]:.2f}] mm\n"
            f"  residual over {fit.n_touches} touches: rms {fit.rms_mm:.3f} mm, max "
            f"{fit.max_mm:.3f} mm")
