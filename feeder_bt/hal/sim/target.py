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

import numpy as np

from ...calibration.camera import Target, TargetPose
from ...calibration.targets import board_rings
from ...jobs import DoneJob, Job
from ...scenario.model import CameraCalibration, CameraSpec
from ..interfaces import Frame, Pose, RobotPosition
from .render import Renderer
from .world import World

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
        self.frames = 0

    def place(self, target: Target | None, pose: TargetPose | None = None) -> None:
        """Lay ``target`` on the belt at ``pose`` (``None``: take it away)."""
        self.outlines = [] if target is None or pose is None else target_polygons(target, pose)

    def grab(self) -> Job:
        self.frames += 1
        rng = np.random.default_rng([self.seed, self.frames])
        img = self.renderer.render(self.outlines, rng)
        return DoneJob("camera.grab", Frame(image=img, latch=0, t=0.0, index=self.frames))

    def set_exposure(self, ms: float) -> Job:
        return DoneJob("camera.set_exposure")


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
