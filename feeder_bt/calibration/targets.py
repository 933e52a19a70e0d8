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

from feeder_bt.calibration.procedure import CalibrationError

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

SUBPIX_FRACTION = 0.2        # chessboard: cornerSubPix half-window, share of a square's side
SUBPIX_MIN, SUBPIX_MAX = 2, 11
GEOMETRY_PX = 2.0            # a point more than this far (px) ...
GEOMETRY_PITCH = 0.15        # ... and this share of the pitch from where its neighbours put it
SHARPNESS_PX = 6.0           # chessboard: edges rising over more px than this ...
SHARPNESS_SHARE = 0.15       # ... and this share of a square: blurred


def _grey(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8 or img.ndim != 2 or img.size == 0:
        raise CalibrationError("the camera image must be an 8-bit grey or colour image")
    return img


def detect_points(image: np.ndarray, target: Target, px_per_mm: float | None = None,
                  check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The target's points found in ``image``: ``(pixels (N, 2), index (N,))``, the index
    into ``points_board().reshape(-1, 2)``. For a grid without a reading of its own
    (chessboard, circles) the index is OpenCV's order (row by row from whichever corner
    OpenCV started at: ``camera.order_grid`` decides).

    OpenCV's own detectors, tuned for the target: the chessboard's sub-pixel window is
    ``SUBPIX_FRACTION`` of the square's side in pixels as found (a fixed window either
    reaches the neighbouring corners of a small board or is too small for a large one;
    ``findChessboardCornersSB`` if the classic detector fails); the circle grid's blob
    detector looks for dots of the expected area (``px_per_mm``, the cell's present scale,
    when given) with OpenCV's shape filters on. ``check``: a view whose points do not fit
    the board's geometry (``geometry_error``) raises ``CalibrationError`` saying which
    point and by how much, never used.
    """
    img = _grey(image)
    size = (target.nx, target.ny)                  # (points per row, rows)
    pts = None
    if target.kind == "chessboard":
        flags = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
                 | cv2.CALIB_CB_FAST_CHECK)          # FAST_CHECK: give up quickly on no board
        found, pts = cv2.findChessboardCorners(img, size, flags=flags)
        if found:
            w = subpix_window(np.asarray(pts, dtype=float).reshape(target.ny, target.nx, 2))
            criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4)
            pts = cv2.cornerSubPix(img, pts, (w, w), (-1, -1), criteria)
        else:
            found, pts = cv2.findChessboardCornersSB(img, size,
                                                     flags=cv2.CALIB_CB_NORMALIZE_IMAGE)
    elif target.kind in ("circles", "dots", "acircles"):
        flag = (cv2.CALIB_CB_ASYMMETRIC_GRID if target.kind == "acircles"
                else cv2.CALIB_CB_SYMMETRIC_GRID)
        found = False
        for det in blob_detectors(img, target, px_per_mm):
            found, pts = cv2.findCirclesGrid(img, size, flags=flag, blobDetector=det)
            if found:
                break
    else:
        board = target.charuco_board()
        corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(img)
        found = ids is not None and len(ids) >= 6
        if found:
            px = np.asarray(corners, dtype=float).reshape(-1, 2)
            index = np.asarray(ids, dtype=int).ravel()
            if check:
                _check_geometry(px, index, target)
            return px, index
    if not found or pts is None:
        raise CalibrationError(f"no {target.describe()} found in the image: is the whole "
                               "target in view, flat, lit and of that size?")
    if check and target.kind == "chessboard":
        _check_sharpness(img, size, pts)
    pts = np.asarray(pts, dtype=float).reshape(-1, 2)
    index = np.arange(len(pts))
    if check:
        _check_geometry(pts, index, target)
    return pts, index


def _check_sharpness(img: np.ndarray, size: tuple[int, int], pts: np.ndarray) -> None:
    """Refuse a blurred chessboard: OpenCV's ``estimateChessboardSharpness`` gives the
    average width (px) over which the board's edges rise; sharp photos give 2.5-3.3 px
    (OpenCV's 9x6 samples), a Gaussian blur of sigma 2 px about 6."""
    try:
        sharp = float(cv2.estimateChessboardSharpness(img, size, np.asarray(
            pts, dtype=np.float32).reshape(-1, 1, 2))[0][0])
    except cv2.error:
        return
    grid = np.asarray(pts, dtype=float).reshape(size[1], size[0], 2)
    side = float(np.median(np.linalg.norm(np.diff(grid, axis=1), axis=-1)))
    limit = max(SHARPNESS_PX, SHARPNESS_SHARE * side)
    if sharp > limit:
        raise CalibrationError(f"the chessboard is blurred: its edges rise over {sharp:.1f} px "
                               f"(limit {limit:.1f}): focus the lens, hold the board still or "
                               "shorten the exposure")


def subpix_window(grid: np.ndarray) -> int:
    """``cornerSubPix``'s half-window for a chessboard found as ``grid`` (``(ny, nx, 2)``
    px): ``SUBPIX_FRACTION`` of the smallest square side, so it never reaches a
    neighbouring corner (on OpenCV's own 9x6 photos, squares 31-45 px: OpenCV's sample
    window of 11 leaves 0.41 px rms, a fifth of the square 0.18 px)."""
    sides = np.concatenate([np.linalg.norm(np.diff(grid, axis=1), axis=-1).ravel(),
                            np.linalg.norm(np.diff(grid, axis=0), axis=-1).ravel()])
    side = float(np.percentile(sides, 10)) if sides.size else 10.0
    return int(np.clip(round(SUBPIX_FRACTION * side), SUBPIX_MIN, SUBPIX_MAX))


def blob_detectors(img: np.ndarray, target: Target, px_per_mm: float | None = None) -> list:
    """Blob detectors to try, best first: dots of the expected size (``px_per_mm``), then
    dots of any size a grid of this many dots can have in this image. OpenCV's shape
    filters (inertia, convexity) stay on: without them a dark corner, a smudge or two dots
    touching through blur pass as dots."""
    out = []
    h, w = img.shape[:2]
    if px_per_mm:
        area = np.pi / 4.0 * (target.dot_mm * px_per_mm) ** 2
        out.append(_blob_detector(0.3 * area, 3.0 * area, target, px_per_mm))
    # any size: from a few pixels up to what fits if the grid filled the image
    n_across = max(target.nx, target.ny) + 1
    biggest = np.pi / 4.0 * (min(h, w) / n_across) ** 2
    out.append(_blob_detector(12.0, max(biggest, 100.0), target, None))
    return out


def _blob_detector(min_area: float, max_area: float, target: Target, px_per_mm: float | None):
    p = cv2.SimpleBlobDetector_Params()          # OpenCV's defaults, then the dot's size
    p.minArea = float(min_area)
    p.maxArea = float(max_area)
    p.filterByInertia = True
    p.minInertiaRatio = 0.2                      # a dot seen at up to ~75 degrees
    p.filterByConvexity = True
    p.minConvexity = 0.85
    if px_per_mm:
        p.minDistBetweenBlobs = max(2.0, 0.5 * (target.spacing - target.dot_mm) * px_per_mm)
    return cv2.SimpleBlobDetector_create(p)


def geometry_error(px: np.ndarray, index: np.ndarray, target: Target
                   ) -> tuple[float, int, float]:
    """How far the points depart from the board's geometry: ``(worst px, its index,
    pitch px)``. Each point is compared with where a homography fitted to its neighbours
    (within two pitches, not itself) puts it: locally a flat board is a homography whatever
    the tilt, and a lens bends it little over two pitches (on OpenCV's 9x6 photos, a strong
    lens and tilt, at most 1.6 px, 0.04 of the pitch)."""
    board = target.points_board().reshape(-1, 2)[index]
    px = np.asarray(px, dtype=float).reshape(-1, 2)
    reach = 2.01 * target.spacing
    d = np.linalg.norm(board[:, None] - board[None], axis=-1)
    worst, at = 0.0, -1
    pitches = []
    for k in range(len(board)):
        near = (d[k] <= reach) & (d[k] > 0)
        if near.sum() < 5:
            continue
        h, _ = cv2.findHomography(board[near], px[near], 0)
        if h is None:
            continue
        q = cv2.perspectiveTransform(board[k].reshape(1, 1, 2), h).reshape(2)
        e = float(np.linalg.norm(q - px[k]))
        if e > worst:
            worst, at = e, k
        nn = (d[k] > 0) & (d[k] <= 1.01 * target.spacing)
        if nn.any():
            pitches.append(float(np.median(np.linalg.norm(px[nn] - px[k], axis=1))))
    pitch_px = float(np.median(pitches)) if pitches else 0.0
    return worst, int(at), pitch_px


def _check_geometry(px: np.ndarray, index: np.ndarray, target: Target) -> None:
    worst, at, pitch_px = geometry_error(px, index, target)
    limit = max(GEOMETRY_PX, GEOMETRY_PITCH * pitch_px)
    if worst > limit:
        u, v = px[at]
        raise CalibrationError(f"the points found do not fit a flat {target.describe()}: the "
                               f"one at ({u:.0f}, {v:.0f}) px is {worst:.1f} px from where its "
                               f"neighbours put it (limit {limit:.1f}): a wrong point, a "
                               "bent board, or not that board")


# ------------------------------------------------------------------------------ drawing


def board_rings(target: Target) -> list[np.ndarray]:
    """The target's dark features as outlines in the board frame (mm): squares, dots, or the
    ChArUco board's black regions (rings parted by NaN rows: ``feeder_bt.core.geometry``). For
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
    from feeder_bt.core.geometry import join_rings

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
