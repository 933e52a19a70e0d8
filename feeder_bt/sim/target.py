"""Calibration rigs for the simulated cell: a target under the camera, a robot that touches.

The procedures in ``feeder_bt.calibration`` see only pixels, robot poses and encoder
counts. These rigs produce them from a ground truth the procedures are not told:

* ``target_polygons`` / ``TargetCamera``: a chessboard's dark squares (or a dot grid's
  dots) as belt-frame polygons, drawn by the ordinary ``Renderer`` through a *truth*
  calibration that may differ from the cell file's (a mis-calibrated camera);
* ``SimToucher``: the operator jogging the robot onto a marker: it moves the simulated
  robot so the tool tip, with a *truth* tool offset, lands on a belt-frame point, with a
  little touch noise; ``RobotFrameView`` reports poses in a robot frame that may be turned
  from the belt frame by a *truth* angle.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from feeder_bt.calibration.camera import Target, TargetPose
from feeder_bt.calibration.procedure import CalibrationError
from feeder_bt.calibration.targets import board_rings
from feeder_bt.core.jobs import DoneJob, Job
from feeder_bt.core.model import CameraCalibration, CameraSpec, CellSpec
from feeder_bt.hal.interfaces import Frame, Pose, RobotPosition
from feeder_bt.sim.render import Renderer
from feeder_bt.sim.world import World

PAPER_GREY = 200.0       # front-lit: a printed board's white paper, grey level
INK_GREY = 30.0          # and its ink


def target_polygons(target: Target, pose: TargetPose) -> list[np.ndarray]:
    """The target's dark features as belt-frame outlines (mm), for ``Renderer.render``:
    a chessboard's dark squares, a grid's dots, a ChArUco board's squares and markers
    (``calibration.targets.board_rings``)."""
    return [pose.to_belt(r) for r in board_rings(target)]


class TargetCamera:
    """A ``Camera`` over a cleared, stopped belt on which a calibration target lies.

    ``truth`` is how the simulated camera really maps pixels to the belt; ``None`` means
    the cell file's calibration is exactly right. Under a front light the board is what
    is printed: dark ink on white paper that fills the view (``PAPER_GREY``, ``INK_GREY``).
    """

    def __init__(self, camera: CameraSpec, truth: CameraCalibration | None = None,
                 seed: int = 1) -> None:
        if camera.render.lighting == "frontlit":
            camera = dataclasses.replace(camera, render=dataclasses.replace(
                camera.render, lighting="backlit", backlight=PAPER_GREY, part_grey=INK_GREY))
        self.renderer = Renderer(camera, truth)
        self.seed = seed
        self.outlines: list[np.ndarray] = []
        self.held: list[np.ndarray] | None = None
        self.frames = 0

    def place(self, target: Target | None, pose: TargetPose | None = None) -> None:
        """Lay ``target`` on the belt at ``pose`` (``None``: take it away)."""
        self.outlines = [] if target is None or pose is None else target_polygons(target, pose)
        if self.renderer.calibration.spec.intrinsics is not None:
            self.outlines = [densify(o) for o in self.outlines]
        self.held = None

    def hold(self, target: Target, pose: TargetPose, tilt_deg: tuple[float, float],
             lift_mm: float) -> None:
        """Hold ``target`` over the belt: centred over ``pose``, lifted ``lift_mm`` towards
        the camera and tilted by ``tilt_deg`` about the belt's x and y axes (the views a
        lens calibration needs). Needs a true camera with a lens (``intrinsics``)."""
        rings = [densify(pose.to_belt(r)) for r in board_rings(target)]
        centre = np.array([pose.x_mm, pose.y_mm, 0.0])
        rot = _rx(tilt_deg[0]) @ _ry(tilt_deg[1])
        k, dist, r, t = camera_pose(self.renderer.calibration.spec)
        up = 1.0 if (-r.T @ t)[2] > 0 else -1.0        # the side of the belt the camera is on
        out = []
        for ring in rings:
            ok = np.isfinite(ring).all(axis=1)
            p3 = np.column_stack([ring - centre[:2], np.zeros(len(ring))]) @ rot.T
            p3 += centre + np.array([0.0, 0.0, up * lift_mm])
            px = np.full((len(ring), 2), np.nan)
            cam = p3[ok] @ r.T + t
            if (cam[:, 2] <= 0).any():
                raise ValueError("the held target is behind the camera")
            px[ok] = cv2.projectPoints(p3[ok].reshape(-1, 1, 3), cv2.Rodrigues(r)[0], t, k,
                                       dist)[0].reshape(-1, 2)
            out.append(px)
        self.held = out
        self.outlines = []

    def grab(self) -> Job:
        self.frames += 1
        rng = np.random.default_rng([self.seed, self.frames])
        if self.held is not None:
            img = self.renderer.render_px(self.held, rng)
        else:
            img = self.renderer.render(self.outlines, rng)
        return DoneJob("camera.grab", Frame(image=img, latch=0, t=0.0, index=self.frames))

    def set_exposure(self, ms: float) -> Job:
        return DoneJob("camera.set_exposure")


def densify(ring: np.ndarray, step_mm: float = 2.0) -> np.ndarray:
    """A polygon's rings (parted by NaN rows) with points every ``step_mm`` along each edge:
    through a lens a straight edge is drawn bent."""
    from feeder_bt.core.geometry import rings as split

    out = []
    for r in split(ring):
        closed = np.vstack([r, r[:1]])
        pts = []
        for a, b in zip(closed[:-1], closed[1:], strict=True):
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / step_mm)))
            pts.append(a + (b - a) * (np.arange(n)[:, None] / n))
        if out:
            out.append(np.full((1, 2), np.nan))
        out.append(np.vstack(pts))
    return np.vstack(out)


def camera_pose(truth: CameraCalibration) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                   np.ndarray]:
    """``(K, dist, R, t)`` of a camera whose belt mapping is ``truth`` (a full calibration:
    intrinsics and homography): belt point ``(x, y, 0)`` -> camera ``R p + t``. The
    homography is ``K [r1 r2 t]`` up to scale, mm -> undistorted px."""
    if truth.intrinsics is None or truth.homography is None:
        raise ValueError("a camera pose needs a calibration with intrinsics and a homography")
    fx, fy, cx, cy = truth.intrinsics
    k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    g = np.linalg.inv(k) @ np.linalg.inv(np.array(truth.homography, dtype=float).reshape(3, 3))
    g /= np.linalg.norm(g[:, 0])
    if g[2, 2] < 0:
        g = -g                                      # the belt in front of the camera
    r1, r2 = g[:, 0], g[:, 1]
    u, _, vt = np.linalg.svd(np.column_stack([r1, r2, np.cross(r1, r2)]))
    r = u @ vt
    return k, np.array(truth.dist, dtype=float), r, g[:, 2]


def _rx(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])


def _ry(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def _rot(deg: float) -> np.ndarray:
    r = math.radians(deg)
    return np.array([[math.cos(r), -math.sin(r)], [math.sin(r), math.cos(r)]])


class RobotFrameView:
    """A ``RobotPosition`` reporting poses in a robot frame turned ``frame_deg`` from the
    belt frame about the robot's base (the simulated world keeps poses in the belt frame)."""

    def __init__(self, world: World, frame_deg: float = 0.0) -> None:
        self.world = world
        self.frame_deg = frame_deg
        self.base = np.array(world.cell.robot.base_mm, dtype=float)

    def to_robot(self, xy: np.ndarray) -> np.ndarray:
        return (np.asarray(xy, dtype=float) - self.base) @ _rot(self.frame_deg).T + self.base

    def to_belt(self, xy: np.ndarray) -> np.ndarray:
        return (np.asarray(xy, dtype=float) - self.base) @ _rot(-self.frame_deg).T + self.base

    def belt_encoder(self) -> int:
        return self.world.robot_count()

    def age(self) -> float | None:
        return 0.0

    def pose(self) -> Pose:
        p = self.world.robot_pose
        x, y = self.to_robot(np.array([p.x, p.y]))
        return Pose(float(x), float(y), p.z, p.rz + self.frame_deg)


class SimToucher:
    """The operator with a teach pendant: puts the tool tip on a point, a little off.

    ``tool_offset_mm`` is the true tip position in the flange frame; ``noise_mm`` the
    standard deviation of each touch, per axis. Poses are commanded in the belt frame;
    ``view`` (optional) turns the commanded ``rz`` into the robot frame's.
    """

    def __init__(self, world: World, robot, tool_offset_mm: tuple[float, float] = (0.0, 0.0),
                 noise_mm: float = 0.05, seed: int = 1,
                 view: RobotPosition | None = None) -> None:
        self.world, self.robot = world, robot
        self.tool = np.asarray(tool_offset_mm, dtype=float)
        self.noise_mm = noise_mm
        self.rng = np.random.default_rng([seed, 7])
        self.frame_deg = getattr(view, "frame_deg", 0.0)
        self.marker: tuple[float, float, float] | None = None   # (x, y, belt position)

    def put_marker(self, x_mm: float, y_mm: float) -> None:
        """Stick a marker on the belt at belt-frame ``(x, y)``; it travels with the belt."""
        self.marker = (x_mm, y_mm, self.world.horizontal.pos(self.world.now()))

    def marker_xy(self) -> np.ndarray:
        if self.marker is None:
            raise RuntimeError("put_marker first")
        x, y, p0 = self.marker
        return np.array([x + self.world.horizontal.pos(self.world.now()) - p0, y])

    def touch(self, point_xy: np.ndarray, rz_robot_deg: float = 0.0) -> Job:
        """Move so the tool tip touches belt-frame ``point_xy`` with the tool turned to
        ``rz_robot_deg`` in the robot frame."""
        rz_belt = rz_robot_deg - self.frame_deg
        flange = np.asarray(point_xy, dtype=float) - _rot(rz_belt) @ self.tool
        flange = flange + self.rng.normal(0.0, self.noise_mm, size=2)
        return self.robot.move_to(Pose(float(flange[0]), float(flange[1]), 0.0, rz_belt))

    def touch_marker(self, rz_robot_deg: float = 0.0) -> Job:
        return self.touch(self.marker_xy(), rz_robot_deg)


# ------------------------------------------------------------------ views for the lens

SIM_LENS_VIEWS = 12            # held views of the target for the simulated lens


def held_poses(n: int, seed: int, room: float = 0.04
               ) -> list[tuple[float, float, float, float, float, float]]:
    """``n`` views of the target held for a lens calibration: (dx, dy in the window's
    share, angle, tilt about x, tilt about y, lift mm): tilted 15-30 degrees every way
    round (a flat target square to the camera cannot tell the focal length) and kept in
    view: ``room`` is how far (a share of the window) the target's centre may go from the
    window's, so a small target is moved round the window and a large one kept in it."""
    rng = np.random.default_rng([seed, 77])
    out = []
    for i in range(n):
        a = 2 * math.pi * i / max(n, 1)
        tilt = 15.0 + 15.0 * rng.random()
        out.append((room * math.cos(a), room * math.sin(a), float(rng.uniform(-5, 5)),
                    tilt * math.cos(a + 0.5), tilt * math.sin(a + 0.5),
                    float(rng.uniform(0, 40))))
    return out


def sim_images(cell: CellSpec, target: Target, pose: TargetPose, truth: CameraCalibration,
               seed: int = 1, views: int = 0, save: str | None = None
               ) -> list[tuple[str, np.ndarray]]:
    """The simulated camera's images of the target: lying at ``pose`` on the belt, then
    ``views`` held over it turned and tilted (for the lens); ``save``: the first to a file."""
    camera = TargetCamera(cell.camera, truth, seed=seed)
    camera.place(target, pose)
    out = [("belt", camera.grab().result.image)]
    if save:
        from feeder_bt.core.images import write_image
        write_image(save, out[0][1])
    if views and truth.intrinsics is None:
        raise CalibrationError("--views: the simulated camera has no lens (sim.lens_focal_px "
                               "0 or sim: {ideal: true}): nothing to calibrate")
    w, h = cell.camera.width_px, cell.camera.height_px
    span = w * cell.camera.calibration.mm_per_px
    board = target.points_board().reshape(-1, 2)
    size = (np.ptp(board, axis=0) + 2 * target.pitch_mm) / cell.camera.calibration.mm_per_px
    room = float(max(0.04, 0.45 * (1.0 - max(size[0] / w, size[1] / h))))
    for i, (du, dv, ang, tx, ty, lift) in enumerate(held_poses(views, seed, room)):
        p = TargetPose(pose.x_mm + dv * span * h / w, pose.y_mm + du * span, pose.angle_deg + ang)
        camera.hold(target, p, (tx, ty), lift)
        out.append((f"held{i + 1:02d}", camera.grab().result.image))
    return out
