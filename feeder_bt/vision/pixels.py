"""Image pixels <-> belt-frame millimetres: the one place the convention lives.

Convention (fixed; the renderer and the locator both use this class):

* image: ``u`` = column (0 at the left), ``v`` = row (0 at the top); integer
  coordinates are pixel centres;
* belt frame: ``x`` = along travel, ``y`` = across the belt, mm;
* with ``s = mm_per_px``, ``r = radians(rotation_deg)``, ``(ox, oy) = origin_mm``::

      x = ox + s * (v cos r - u sin r)
      y = oy + s * (v sin r + u cos r)

The image's ``v`` axis runs along the belt, so the mapping swaps axes: it is a
*reflection* (determinant ``-s²``). A shape's handedness flips between the image and
the belt frame, so chirality and orientation must be computed after mapping contour
points to mm, never in pixels.

A full calibration (``feeder calibrate camera`` with several views) adds the lens and a
tilted camera: pixels are first undistorted (``cv2.undistortPoints`` with the camera
matrix and OpenCV's distortion coefficients, back to pixel units), then mapped to the belt
by a homography (``CameraCalibration.homography``) instead of the similarity. Only the
points the locator reports are undistorted, never the whole image. ``mm_per_px`` stays the
similarity's scale: areas and lengths in pixels are converted with it, which is right to
the few per mille a tilt or a lens changes the scale over the window.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from feeder_bt.core.model import CameraCalibration


def shifted(cal: CameraCalibration, offset_mm: tuple[float, float], scale_pct: float,
            rotation_deg: float) -> CameraCalibration:
    """``cal`` moved in the belt frame by ``offset_mm``, scaled by ``scale_pct`` and turned by
    ``rotation_deg`` about its origin (a homography gets the same move)."""
    o = np.array(cal.origin_mm, dtype=float)
    f = 1.0 + scale_pct / 100.0
    hom = cal.homography
    if hom is not None:
        r = math.radians(rotation_deg)
        a = f * np.array([[math.cos(r), -math.sin(r)], [math.sin(r), math.cos(r)]])
        move = np.eye(3)
        move[:2, :2] = a
        move[:2, 2] = o + np.asarray(offset_mm, dtype=float) - a @ o
        h = move @ np.array(hom, dtype=float).reshape(3, 3)
        hom = [float(v) for v in (h / h[2, 2]).ravel()]
    return CameraCalibration(
        origin_mm=(float(o[0] + offset_mm[0]), float(o[1] + offset_mm[1])),
        mm_per_px=cal.mm_per_px * f, rotation_deg=cal.rotation_deg + rotation_deg,
        intrinsics=cal.intrinsics, dist=list(cal.dist), homography=hom)


def turned_about(cal: CameraCalibration, centre_mm: tuple[float, float],
                 deg: float) -> CameraCalibration:
    """``cal`` with every point it maps turned by ``deg`` about ``centre_mm`` (belt frame):
    a calibration whose target was laid turned, put square to the belt's travel about the
    one point the person placed for sure, the target's centre."""
    r = math.radians(deg)
    rot = np.array([[math.cos(r), -math.sin(r)], [math.sin(r), math.cos(r)]])
    o, c = np.asarray(cal.origin_mm, dtype=float), np.asarray(centre_mm, dtype=float)
    off = c + rot @ (o - c) - o
    return shifted(cal, (float(off[0]), float(off[1])), 0.0, deg)


class Calibration:
    """Vectorised pixel <-> mm mapping built from a cell's ``CameraCalibration``."""

    def __init__(self, spec: CameraCalibration) -> None:
        self.spec = spec
        s = float(spec.mm_per_px)
        if s <= 0:
            raise ValueError("mm_per_px must be positive")
        r = math.radians(spec.rotation_deg)
        c, n = math.cos(r), math.sin(r)
        self._s = s
        # [x, y] = origin + s * M @ [u, v], with M symmetric and M @ M = I.
        self._m = np.array([[-n, c], [c, n]])
        self._fwd = s * self._m              # px -> mm (applied to row vectors via .T)
        self._inv = self._m / s              # mm -> px
        self._origin = np.array(spec.origin_mm, dtype=float)
        self._k: np.ndarray | None = None
        self._dist: np.ndarray | None = None
        intr = getattr(spec, "intrinsics", None)
        dist = list(getattr(spec, "dist", None) or [])
        if intr is not None and any(dist):
            fx, fy, cx, cy = (float(v) for v in intr)
            if not (fx > 0 and fy > 0):
                raise ValueError("intrinsics: focal lengths must be positive")
            if len(dist) not in (4, 5, 8, 12, 14):
                raise ValueError(f"dist: OpenCV takes 4, 5, 8, 12 or 14 coefficients, got "
                                 f"{len(dist)}")
            self._k = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
            self._dist = np.array(dist, dtype=float)
        hom = getattr(spec, "homography", None)
        self._h: np.ndarray | None = None
        if hom is not None:
            h = np.array(hom, dtype=float)
            if h.size != 9 or not np.isfinite(h).all() or np.linalg.det(h.reshape(3, 3)) == 0:
                raise ValueError("homography: expected 9 finite numbers of an invertible 3x3")
            self._h = h.reshape(3, 3)
            self._hinv = np.linalg.inv(self._h)

    @property
    def mm_per_px(self) -> float:
        return self._s

    @property
    def mm2_per_px2(self) -> float:
        return self._s * self._s

    @property
    def linear(self) -> bool:
        """Whether the mapping is the plain similarity (no lens, no homography)."""
        return self._k is None and self._h is None

    def local_scale(self, uv: np.ndarray) -> np.ndarray:
        """mm per px at each of ``(N, 2)`` pixels: the square root of the mapping's area
        scale there (``mm_per_px`` everywhere for a similarity)."""
        return self.px_to_mm_scale(uv)[1]

    def px_to_mm_scale(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``px_to_mm`` and ``local_scale`` of the same pixels in one mapping (the
        locator's centroids: one undistortion a frame, not two)."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if self.linear or len(uv) == 0:
            return self.px_to_mm(uv), np.full(len(uv), self._s)
        p = self.px_to_mm(np.vstack([uv, uv + [1.0, 0.0], uv + [0.0, 1.0]])).reshape(3, -1, 2)
        du, dv = p[1] - p[0], p[2] - p[0]
        return p[0], np.sqrt(np.abs(du[:, 0] * dv[:, 1] - du[:, 1] * dv[:, 0]))

    def undistort(self, uv: np.ndarray) -> np.ndarray:
        """``(N, 2)`` pixels -> where an ideal (distortion-free) lens would have put them."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if self._k is None or len(uv) == 0:
            return uv
        out = np.full_like(uv, np.nan)
        ok = np.isfinite(uv).all(axis=1)
        if ok.any():
            # iterative: a few more iterations than the default 5 for a strong lens
            crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 1e-9)
            out[ok] = cv2.undistortPoints(uv[ok].reshape(-1, 1, 2), self._k, self._dist,
                                          R=None, P=self._k, criteria=crit).reshape(-1, 2)
        return out

    def distort(self, uv: np.ndarray) -> np.ndarray:
        """The inverse of ``undistort``: ideal pixels -> where the lens puts them."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        if self._k is None or len(uv) == 0:
            return uv
        out = np.full_like(uv, np.nan)
        ok = np.isfinite(uv).all(axis=1)
        if ok.any():
            k = self._k
            xn = (uv[ok, 0] - k[0, 2]) / k[0, 0]
            yn = (uv[ok, 1] - k[1, 2]) / k[1, 1]
            obj = np.column_stack([xn, yn, np.ones_like(xn)]).reshape(-1, 1, 3)
            z = np.zeros(3)
            out[ok] = cv2.projectPoints(obj, z, z, k, self._dist)[0].reshape(-1, 2)
        return out

    def px_to_mm(self, uv: np.ndarray) -> np.ndarray:
        """``(N, 2)`` pixel ``(u, v)`` -> ``(N, 2)`` belt ``(x, y)`` mm."""
        uv = self.undistort(uv)
        if self._h is not None:
            return _apply(self._h, uv)
        return uv @ self._fwd.T + self._origin

    def _kernel_table(self) -> tuple[int, np.ndarray, np.ndarray]:
        """How ``vision.kernels`` maps pixels with this calibration: only a similarity can
        be (``linear``); others go through their ``PixelGrid``."""
        if not self.linear:
            raise ValueError("a lens or homography maps through its PixelGrid")
        f = self._fwd
        return 0, _NO_CELLS, np.array([f[0, 0], f[0, 1], f[1, 0], f[1, 1], *self._origin,
                                       self._s])

    def mm_to_px(self, xy: np.ndarray) -> np.ndarray:
        """``(N, 2)`` belt ``(x, y)`` mm -> ``(N, 2)`` pixel ``(u, v)``."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        uv = _apply(self._hinv, xy) if self._h is not None else (xy - self._origin) @ self._inv.T
        return self.distort(uv)


_NO_CELLS = np.zeros((1, 4, 3))      # a similarity's (unused) table for the kernels


def _apply(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """A homography on ``(N, 2)`` points (NaN rows stay NaN)."""
    q = pts @ h[:, :2].T + h[:, 2]
    return q[:, :2] / q[:, 2:3]


class PixelGrid:
    """A calibration's ``px_to_mm_scale`` over one image size, read from a table.

    Through a lens the exact mapping undistorts each point iteratively and applies the
    homography: tens of microseconds of per-call overhead a frame, which was a sixth of the
    locator's time on a frame of lenses (benchmarks/vision_bench.py). The table holds the
    exact mapping (x, y mm and the local mm per px) at every ``step`` pixels, a little
    beyond the image, and points are read from it by bilinear interpolation: over a
    ``step``-pixel cell a lens and a tilt are smooth enough for that to be the mapping to
    well under a thousandth of a mm (tests/config/test_parts_model.py). Built once per image size.
    """

    def __init__(self, calibration: Calibration, shape: tuple[int, int], step: int = 4) -> None:
        h, w = shape[:2]
        self.shape = (h, w)
        self.step = float(step)
        us = np.arange(-2 * step, w + 2 * step + 1, step, dtype=float)
        vs = np.arange(-2 * step, h + 2 * step + 1, step, dtype=float)
        uu, vv = np.meshgrid(us, vs)
        xy, scale = calibration.px_to_mm_scale(np.column_stack([uu.ravel(), vv.ravel()]))
        t = np.column_stack([xy, scale]).reshape(len(vs), len(us), 3)
        a, b, c, d = t[:-1, :-1], t[:-1, 1:], t[1:, :-1], t[1:, 1:]
        # per cell, the bilinear form's coefficients of 1, fu, fv and fu·fv: one gather
        # and one product a point
        cells = np.stack([a, b - a, c - a, a - b - c + d], axis=2)    # (nv-1, nu-1, 4, 3)
        self._cells = np.ascontiguousarray(cells.reshape(-1, 4, 3))
        self._par = np.array([us[0], vs[0], 1.0 / step, len(us) - 2, len(vs) - 2,
                              len(us) - 1], dtype=float)

    def _kernel_table(self) -> tuple[int, np.ndarray, np.ndarray]:
        """The table as ``vision.kernels`` reads it (``kernels._to_mm``)."""
        return 1, self._cells, self._par

    def px_to_mm_scale(self, uv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(N, 2)`` pixels -> belt mm ``(N, 2)`` and mm per px ``(N,)`` (as
        ``Calibration.px_to_mm_scale``; points off the table are extrapolated linearly).
        Each point: its cell's bilinear form's coefficients of 1, fu, fv and fu·fv."""
        from feeder_bt.vision.jit import kernels
        uv = np.ascontiguousarray(np.asarray(uv, dtype=float).reshape(-1, 2))
        out = kernels().map_points(uv, 1, self._cells, self._par)
        return out[:, :2], out[:, 2]

    def px_to_mm(self, uv: np.ndarray) -> np.ndarray:
        """``(N, 2)`` pixels -> belt mm, from the table."""
        return self.px_to_mm_scale(uv)[0]
