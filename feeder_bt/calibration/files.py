"""Calibration files: what ``feeder calibrate ... --write`` writes, and how a cell uses one.

A cell description may name its camera calibration file instead of (or as well as)
writing the numbers inline::

    camera:
      calibration_file: calibration/camera.yaml     # relative to the cell file

The file's ``origin_mm``, ``mm_per_px`` and ``rotation_deg`` (and, from a full
calibration, ``intrinsics``, ``dist`` and ``homography``: ``vision.calibration``) then
replace ``camera.calibration``; anything else in it (residuals, date, target) is a record
for people. An old file of the three similarity keys alone is read as before. So recalibrating a cell rewrites one small file and never the cell description.
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

from feeder_bt.core.errors import ConfigError
from feeder_bt.core.model import CameraCalibration, CellSpec

REQUIRED = ("origin_mm", "mm_per_px", "rotation_deg")
_CONSTRUCT = yaml.constructor.SafeConstructor()


def write_calibration_file(path: str | Path, values: dict[str, Any], header: str) -> Path:
    """Write ``values`` as YAML under a ``# header`` comment; returns the path written."""
    path = Path(path)
    text = "".join(f"# {line}\n" for line in header.splitlines())
    text += yaml.safe_dump(values, sort_keys=False, default_flow_style=None)
    try:
        if path.parent and not path.parent.exists():
            path.parent.mkdir(parents=True)
        path.write_text(text, encoding="utf-8")
    except OSError as e:
        raise ConfigError(f"cannot write: {e.strerror or e}", file=str(path)) from None
    return path


def _beside_cell(cell: CellSpec, name: str | None) -> Path | None:
    """A file a cell names, resolved against the cell file's folder."""
    if not name:
        return None
    p = Path(name)
    return p if p.is_absolute() else Path(os.path.normpath(Path(cell.path).parent / p))


def calibration_path(cell: CellSpec) -> Path | None:
    """The camera calibration file a cell names."""
    return _beside_cell(cell, getattr(cell.camera, "calibration_file", None))


def _read_mapping(path: str | Path, required: tuple[str, ...], command: str
                  ) -> dict[str, Any]:
    """A calibration file's top-level keys -> YAML nodes; every problem is one
    ``FILE:LINE: key:`` line (``command`` says how to write the file)."""
    file = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"calibration file not found (write it with `{command}`)",
                          file=file) from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(f"cannot read: {getattr(e, 'strerror', None) or e}",
                          file=file) from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        raise ConfigError(f"YAML syntax error: {getattr(e, 'problem', None) or e}", file=file,
                          line=mark.line + 1 if mark else None) from None
    if not isinstance(root, MappingNode):
        raise ConfigError(f"expected a mapping with {', '.join(required)}",
                          file=file, line=root.start_mark.line + 1 if root else 1)
    nodes: dict[str, Any] = {}
    for k, v in root.value:
        key = k.value if isinstance(k, ScalarNode) else str(k)
        if key in nodes:
            raise ConfigError(f"duplicate key {key!r}", file=file, line=k.start_mark.line + 1,
                              key=key)
        nodes[key] = v
    for key in required:
        if key not in nodes:
            raise ConfigError(f"missing required key {key!r}", file=file,
                              line=root.start_mark.line + 1)
    return nodes


def _number(node: Any, key: str, file: str) -> float:
    line = node.start_mark.line + 1
    v = _CONSTRUCT.construct_object(node) if isinstance(node, ScalarNode) else None
    if isinstance(v, str) and node.style is None:      # PyYAML reads 1e3 as a string
        try:
            v = float(v)
        except ValueError:
            pass
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise ConfigError(f"expected a finite number, got {_show(node)}", file=file,
                          line=line, key=key)
    return float(v)


def _pair(node: Any, key: str, file: str) -> tuple[float, float]:
    if not isinstance(node, SequenceNode) or len(node.value) != 2:
        raise ConfigError(f"expected [x, y] in mm, got {_show(node)}", file=file,
                          line=node.start_mark.line + 1, key=key)
    return (_number(node.value[0], key, file), _number(node.value[1], key, file))


def _angle(node: Any, key: str, file: str) -> float:
    r = _number(node, key, file)
    if not -180.0 <= r <= 180.0:
        raise ConfigError(f"must be in [-180, 180], got {r:g}", file=file,
                          line=node.start_mark.line + 1, key=key)
    return r


def read_camera_calibration(path: str | Path) -> CameraCalibration:
    """Read and check a camera calibration file; every problem is one ``FILE:LINE: key:``
    line."""
    file = str(path)
    nodes = _read_mapping(path, REQUIRED, "feeder calibrate camera CELL --write FILE")
    origin = _pair(nodes["origin_mm"], "origin_mm", file)
    s = _number(nodes["mm_per_px"], "mm_per_px", file)
    if s <= 0:
        raise ConfigError(f"must be > 0, got {s:g}", file=file,
                          line=nodes["mm_per_px"].start_mark.line + 1, key="mm_per_px")
    r = _angle(nodes["rotation_deg"], "rotation_deg", file)

    def numbers(key: str, sizes: tuple[int, ...], what: str) -> list[float] | None:
        node = nodes.get(key)
        if node is None:
            return None
        if not isinstance(node, SequenceNode) or len(node.value) not in sizes:
            raise ConfigError(f"expected {what}, got {_show(node)}"
                              + (f" of {len(node.value)}" if isinstance(node, SequenceNode)
                                 else ""), file=file, line=node.start_mark.line + 1, key=key)
        return [_number(v, key, file) for v in node.value]

    intr = numbers("intrinsics", (4,), "[fx, fy, cx, cy] in px")
    if intr is not None and not (intr[0] > 0 and intr[1] > 0):
        raise ConfigError(f"focal lengths must be > 0, got {intr[0]:g}, {intr[1]:g}", file=file,
                          line=nodes["intrinsics"].start_mark.line + 1, key="intrinsics")
    dist = numbers("dist", (4, 5, 8, 12, 14), "OpenCV's 4, 5, 8, 12 or 14 distortion "
                   "coefficients") or []
    if dist and intr is None:
        raise ConfigError("distortion without intrinsics: give intrinsics [fx, fy, cx, cy]",
                          file=file, line=nodes["dist"].start_mark.line + 1, key="dist")
    hom = numbers("homography", (9,), "9 numbers (a 3x3 homography, row by row)")
    if hom is not None and np.linalg.det(np.array(hom).reshape(3, 3)) == 0:
        raise ConfigError("the homography is singular", file=file,
                          line=nodes["homography"].start_mark.line + 1, key="homography")
    return CameraCalibration(origin_mm=origin, mm_per_px=s, rotation_deg=r,
                             intrinsics=tuple(intr) if intr else None, dist=dist,
                             homography=hom)


def _show(node: Any) -> str:
    if isinstance(node, ScalarNode):
        return repr(node.value)[:40]
    return "a list" if isinstance(node, SequenceNode) else "a mapping"


def apply_calibration_file(cell: CellSpec, line: int | None = None) -> CellSpec:
    """The cell with ``camera.calibration`` replaced by its ``camera.calibration_file``'s.

    A cell without ``calibration_file`` comes back unchanged (the same object). ``line``
    (of the key in the cell file) only makes a missing-file message point at it.
    """
    path = calibration_path(cell)
    if path is None:
        return cell
    if not path.is_file():
        what = "is not a file" if path.exists() else "not found"
        raise ConfigError(f"calibration file {cell.camera.calibration_file!r} {what} (looked "
                          f"for {path}; write it with `feeder calibrate camera CELL --write "
                          "FILE`)", file=str(cell.path), line=line,
                          key="camera.calibration_file")
    cal = read_camera_calibration(path)
    camera = dataclasses.replace(cell.camera, calibration=cal)
    return dataclasses.replace(cell, camera=camera)


# ---------------------------------------------------------------------------- robot frame
# FRAME_SPEC: ``robot.frame_file`` names a file holding ``base_mm: [x, y]`` and
# ``base_deg: a``, the robot base's pose in the cell frame, which `feeder commission adept`
# fits from touch points; its values replace ``robot.base_mm``/``robot.base_deg``.
FRAME_REQUIRED = ("base_mm", "base_deg")


def robot_frame_path(cell: CellSpec) -> Path | None:
    """The robot frame file a cell names."""
    return _beside_cell(cell, getattr(cell.robot, "frame_file", None))


def read_robot_frame(path: str | Path) -> tuple[tuple[float, float], float]:
    """``(base_mm, base_deg)`` from a robot frame file; problems are ``FILE:LINE: key:``."""
    file = str(path)
    nodes = _read_mapping(path, FRAME_REQUIRED, "feeder commission adept CELL")
    return (_pair(nodes["base_mm"], "base_mm", file),
            _angle(nodes["base_deg"], "base_deg", file))


def apply_robot_frame_file(cell: CellSpec, line: int | None = None) -> CellSpec:
    """The cell with ``robot.base_mm``/``base_deg`` from its ``robot.frame_file`` (the same
    object when it names none)."""
    path = robot_frame_path(cell)
    if path is None:
        return cell
    if not path.is_file():
        what = "is not a file" if path.exists() else "not found"
        raise ConfigError(f"robot frame file {cell.robot.frame_file!r} {what} (looked for "
                          f"{path}; write it with `feeder commission adept CELL`)",
                          file=str(cell.path), line=line, key="robot.frame_file")
    base, deg = read_robot_frame(path)
    changes: dict[str, Any] = {"base_mm": base}
    if any(f.name == "base_deg" for f in dataclasses.fields(cell.robot)):
        changes["base_deg"] = deg
    elif abs(deg) > 1e-9:
        raise ConfigError(f"base_deg {deg:g}: this version has no robot.base_deg (a turned "
                          "robot base)", file=str(path), key="base_deg")
    return dataclasses.replace(cell, robot=dataclasses.replace(cell.robot, **changes))
