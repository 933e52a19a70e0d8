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
"""

from __future__ import annotations

import math

import numpy as np

from ..scenario.model import CameraCalibration


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

    @property
    def mm_per_px(self) -> float:
        return self._s

    @property
    def mm2_per_px2(self) -> float:
        return self._s * self._s

    def px_to_mm(self, uv: np.ndarray) -> np.ndarray:
        """``(N, 2)`` pixel ``(u, v)`` -> ``(N, 2)`` belt ``(x, y)`` mm."""
        uv = np.asarray(uv, dtype=float).reshape(-1, 2)
        return uv @ self._fwd.T + self._origin

    def mm_to_px(self, xy: np.ndarray) -> np.ndarray:
        """``(N, 2)`` belt ``(x, y)`` mm -> ``(N, 2)`` pixel ``(u, v)``."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return (xy - self._origin) @ self._inv.T
