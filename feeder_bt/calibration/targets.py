"""Calibration targets: what a board looks like, where its points are, how to find them.

Kinds (``Target.kind``):

* ``chessboard``: ``nx`` x ``ny`` inner corners ``pitch_mm`` apart (a board of ``nx + 1``
  by ``ny + 1`` squares); the square at the board's (-x, -y) corner is dark.
* ``circles`` (``dots`` is its old name): a symmetric grid of ``nx`` x ``ny`` dark dots
  ``dot_mm`` across, ``pitch_mm`` apart.
* ``acircles``: OpenCV's asymmetric grid: ``ny`` rows of ``nx`` dots, each row
  ``pitch_mm / 2`` from the last and shifted by half the ``pitch_mm`` between the dots of a
  row — it has one reading, however it lies.
* ``charuco``: a chessboard of ``nx + 1`` by ``ny + 1`` squares with an ArUco marker
  (``marker_mm``, from ``dictionary``) in each light square (OpenCV's ``CharucoBoard``); its
  ``nx`` x ``ny`` inner corners are identified by the markers, so part of the board is
  enough and it has one reading.

The board frame's origin is the centre of the points (for ``acircles`` the centre of their
bounding box); board x runs along a row.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .common import CalibrationError

KINDS = ("chessboard", "circles", "acircles", "charuco", "dots")
MARKER_FRACTION = 0.7          # charuco: default marker side / square side
BOARD_PX_PER_MM = 10           # charuco: the board drawn this finely for its outlines


@dataclass(frozen=True)
class Target:
    """A calibration target (see the module docstring)."""

    kind: str = "chessboard"
    nx: int = 8
    ny: int = 12
    pitch_mm: float = 40.0
    dot_mm: float = 14.0
    marker_mm: float = 0.0           # charuco: 0 -> MARKER_FRACTION of the pitch
    dictionary: str = "DICT_4X4_250"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise CalibrationError(f"target kind must be one of {', '.join(KINDS[:-1])}, got "
                                   f"{self.kind!r}")
        if self.nx < 2 or self.ny < 2:
            raise CalibrationError(f"a target needs at least 2x2 points, got {self.nx}x{self.ny}")
        if not self.pitch_mm > 0:
            raise CalibrationError(f"target pitch_mm must be > 0, got {self.pitch_mm:g}")
        if self.kind in ("circles", "dots", "acircles") and not 0 < self.dot_mm < self.spacing:
            raise CalibrationError(f"target dot_mm must be > 0 and < the dots' spacing "
                                   f"{self.spacing:g} mm, got {self.dot_mm:g}")
        if self.kind == "charuco":
            if not 0 < self.marker < self.pitch_mm:
                raise CalibrationError(f"target marker_mm must be > 0 and < pitch_mm "
                                       f"{self.pitch_mm:g}, got {self.marker:g}")
            if not self.dictionary.startswith("DICT_") or \
                    not hasattr(cv2.aruco, self.dictionary):
                raise CalibrationError(f"target dictionary {self.dictionary!r} is not one of "
                                       "OpenCV's (e.g. DICT_4X4_250, DICT_5X5_100)")
            need = self.nx * self.ny // 2 + self.nx + self.ny + 2
            size = int(self.dictionary.rsplit("_", 1)[1])
            if size < need:
                raise CalibrationError(f"a {self.nx + 1}x{self.ny + 1}-square ChArUco board "
                                       f"needs about {need} markers; {self.dictionary} has "
                                       f"{size}")

    @property
    def marker(self) -> float:
        """Charuco: the marker side, mm."""
        return self.marker_mm or MARKER_FRACTION * self.pitch_mm

    @property
    def spacing(self) -> float:
        """Distance between neighbouring points (an asymmetric grid's diagonal spacing)."""
        return self.pitch_mm / np.sqrt(2.0) if self.kind == "acircles" else self.pitch_mm

    @property
    def unique(self) -> bool:
        """Whether the detected points have one reading (no flip or turn to choose)."""
        return self.kind in ("acircles", "charuco")

    def describe(self) -> str:
        what = {"chessboard": "chessboard of {nx}x{ny} inner corners",
                "circles": "{nx}x{ny} grid of dots", "dots": "{nx}x{ny} grid of dots",
                "acircles": "asymmetric {nx}x{ny} grid of dots",
                "charuco": "ChArUco board of {nx}x{ny} inner corners"}[self.kind]
        return what.format(nx=self.nx, ny=self.ny) + f", {self.pitch_mm:g} mm"

    def points_board(self) -> np.ndarray:
        """``(ny, nx, 2)`` feature points in the board frame (mm), row by row."""
        i, j = np.meshgrid(np.arange(self.nx, dtype=float), np.arange(self.ny, dtype=float))
        p = self.pitch_mm
        if self.kind == "acircles":
            bx = (i + (j % 2) / 2.0) * p
            by = j * p / 2.0
            bx -= (bx.min() + bx.max()) / 2.0
            by -= (by.min() + by.max()) / 2.0
        else:
            bx = (i - (self.nx - 1) / 2.0) * p
            by = (j - (self.ny - 1) / 2.0) * p
        return np.stack([bx, by], axis=-1)

    def charuco_board(self):
        """OpenCV's ``CharucoBoard`` of this target (its own frame: mm from a corner)."""
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.nx + 1, self.ny + 1), self.pitch_mm, self.marker,
                                      d)


DEFAULT_TARGETS = {
    "chessboard": Target("chessboard", nx=8, ny=12, pitch_mm=40.0),
    "dots": Target("dots", nx=9, ny=13, pitch_mm=36.0, dot_mm=14.0),
    "circles": Target("circles", nx=9, ny=13, pitch_mm=36.0, dot_mm=14.0),
    "acircles": Target("acircles", nx=6, ny=15, pitch_mm=60.0, dot_mm=14.0),
    "charuco": Target("charuco", nx=8, ny=11, pitch_mm=40.0, marker_mm=28.0),
}


def parse_board(text: str) -> tuple[int, int]:
    """``"7x9"`` -> (7, 9): points per row and rows."""
    try:
        nx, ny = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise CalibrationError(f"--board {text!r}: give points per row and rows as NXxNY, "
                               "e.g. 7x9") from None
    return nx, ny


# ------------------------------------------------------------------------------ detection


def detect_points(image: np.ndarray, target: Target) -> tuple[np.ndarray, np.ndarray]:
    """The target's points found in ``image``: ``(pixels (N, 2), index (N,))``, the index
    into ``points_board().reshape(-1, 2)``. For a grid without a reading of its own
    (chessboard, circles) the index is OpenCV's order (row by row from whichever corner
    OpenCV started at: ``camera.order_grid`` decides)."""
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8 or img.ndim != 2 or img.size == 0:
        raise CalibrationError("the camera image must be an 8-bit grey or colour image")
    size = (target.nx, target.ny)                  # (points per row, rows)
    pts = None
    if target.kind == "chessboard":
        flags = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                 | cv2.CALIB_CB_FAST_CHECK)          # FAST_CHECK: give up quickly on no board
        found, pts = cv2.findChessboardCorners(img, size, flags=flags)
        if found:
            criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
            pts = cv2.cornerSubPix(img, pts, (5, 5), (-1, -1), criteria)
    elif target.kind in ("circles", "dots", "acircles"):
        flag = (cv2.CALIB_CB_ASYMMETRIC_GRID if target.kind == "acircles"
                else cv2.CALIB_CB_SYMMETRIC_GRID)
        found, pts = cv2.findCirclesGrid(img, size, flags=flag,
                                         blobDetector=_blob_detector(img, target))
    else:
        board = target.charuco_board()
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(img)
        found = ids is not None and len(ids) >= 6
        if found:
            return (np.asarray(corners, dtype=float).reshape(-1, 2),
                    np.asarray(ids, dtype=int).ravel())
    if not found or pts is None:
        raise CalibrationError(f"no {target.describe()} found in the image: is the whole "
                               "target in view, flat, lit and of that size?")
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    return pts, np.arange(len(pts))


def _blob_detector(img: np.ndarray, target: Target):
    """A blob detector for dots of any size (OpenCV's default stops at 5000 px²)."""
    p = cv2.SimpleBlobDetector_Params()
    p.minArea = 10.0
    p.maxArea = float(img.size) / 4.0
    p.filterByConvexity = False
    p.filterByInertia = False
    return cv2.SimpleBlobDetector_create(p)


# ------------------------------------------------------------------------------ drawing


def board_rings(target: Target) -> list[np.ndarray]:
    """The target's dark features as outlines in the board frame (mm): squares, dots, or the
    ChArUco board's black regions (rings parted by NaN rows: ``feeder_bt.geometry``). For
    drawing test boards (the simulated camera renders them)."""
    if target.kind == "charuco":
        return _charuco_rings(target)
    p = target.pitch_mm
    out: list[np.ndarray] = []
    if target.kind == "chessboard":
        x0 = -(target.nx + 1) / 2.0 * p
        y0 = -(target.ny + 1) / 2.0 * p
        for j in range(target.ny + 1):
            for i in range(target.nx + 1):
                if (i + j) % 2 == 0:
                    x, y = x0 + i * p, y0 + j * p
                    out.append(np.array([[x, y], [x + p, y], [x + p, y + p], [x, y + p]]))
        return out
    a = np.linspace(0.0, 2 * np.pi, 48, endpoint=False)
    ring = 0.5 * target.dot_mm * np.column_stack([np.cos(a), np.sin(a)])
    return [ring + c for c in target.points_board().reshape(-1, 2)]


def _charuco_rings(target: Target) -> list[np.ndarray]:
    """OpenCV draws the board; its dark squares are read off the drawing (a pixel in each
    square's corner, clear of any marker) and drawn exactly, and the markers (each clear of
    the squares) become outlines with their white cells as holes."""
    from ..geometry import join_rings

    k, p = BOARD_PX_PER_MM, target.pitch_mm
    nsx, nsy = target.nx + 1, target.ny + 1
    sq = round(p * k)
    img = target.charuco_board().generateImage((nsx * sq, nsy * sq), marginSize=0,
                                               borderBits=1)
    x0, y0 = -nsx * p / 2.0, -nsy * p / 2.0
    out: list[np.ndarray] = []
    for j in range(nsy):
        for i in range(nsx):
            if img[j * sq + 1, i * sq + 1] < 128:
                img[j * sq:(j + 1) * sq, i * sq:(i + 1) * sq] = 255     # leave the markers
                x, y = x0 + i * p, y0 + j * p
                out.append(np.array([[x, y], [x + p, y], [x + p, y + p], [x, y + p]]))
    dark = (img < 128).astype(np.uint8)
    contours, hier = cv2.findContours(dark, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if hier is None:
        return out
    hier = hier.reshape(-1, 4)
    scale = p / sq                                   # mm per drawing pixel

    def mm(c: np.ndarray, grow: float) -> np.ndarray:
        # contour points are pixel centres: move them half a pixel out to the edge (in,
        # for a hole's)
        q = c.reshape(-1, 2).astype(float) + 0.5
        q += grow * 0.5 * np.sign(q - q.mean(axis=0))
        return q * scale + np.array([x0, y0])

    for i, c in enumerate(contours):
        if hier[i, 3] < 0:
            holes = [mm(contours[h], -1.0) for h in range(len(contours)) if hier[h, 3] == i]
            out.append(join_rings([mm(c, 1.0), *holes]))
    return out
