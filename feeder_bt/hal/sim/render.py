"""Camera images of the backlit belt, for the simulated cell.

Realism the locator has to cope with: a backlight that falls off towards the corners
(vignetting), dark anti-aliased part silhouettes with a little texture, optical blur and
sensor noise. Parts are drawn through the *truth* calibration, which the simulator may
set apart from the cell's calibration to model a mis-calibrated camera.

Speed (about 1 ms a 640x484 frame): the background is precomputed, each part is
supersampled only in its own bounding box, and the noise comes from random bytes
through a Gaussian look-up table instead of ``rng.normal`` (4x faster).
"""

from __future__ import annotations

from statistics import NormalDist

import cv2
import numpy as np

from ...scenario.model import CameraCalibration, CameraSpec
from ...vision.calibration import Calibration

SUPERSAMPLE = 4                      # sub-pixels per pixel, each axis, for anti-aliasing
_SHIFT = 4                           # fillPoly fractional bits
_TEXTURE_GREY = 4.0                  # amplitude of the parts' texture, grey levels
_TEXTURE_PAD = 64                    # the texture field is larger than the frame: random offset


def _gaussian_lut() -> np.ndarray:
    """Quantiles of N(0, 1) at the 256 byte values: random bytes -> Gaussian noise."""
    nd = NormalDist()
    return np.array([nd.inv_cdf((i + 0.5) / 256.0) for i in range(256)], dtype=np.float32)


class Renderer:
    """Renders frames of the camera window; outlines are in belt-frame mm."""

    def __init__(self, camera: CameraSpec, truth: CameraCalibration | None = None) -> None:
        self.camera = camera
        self.spec = camera.render
        self.calibration = Calibration(truth if truth is not None else camera.calibration)
        h, w = camera.height_px, camera.width_px
        self.shape = (h, w)
        rs = self.spec
        # Vignetting: brightness falls with the squared distance from the centre and has
        # lost `falloff` of it in the corners.
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
        cu, cv = (w - 1) / 2.0, (h - 1) / 2.0
        r2 = ((uu - cu) ** 2 + (vv - cv) ** 2) / (cu * cu + cv * cv)
        self._background = (rs.backlight * (1.0 - rs.falloff * r2)).astype(np.float32)
        # A smooth, fixed texture field for the parts (moulding marks, dust, thickness).
        trng = np.random.default_rng(12345)
        tex = trng.standard_normal((h + _TEXTURE_PAD, w + _TEXTURE_PAD)).astype(np.float32)
        tex = cv2.GaussianBlur(tex, (0, 0), 3.0)
        tex *= _TEXTURE_GREY / max(float(tex.std()), 1e-6)
        self._texture = tex + np.float32(rs.part_grey)
        self._noise_lut = (_gaussian_lut() * np.float32(rs.noise_sigma)).reshape(1, 256)
        self._pad = int(np.ceil(3 * max(rs.blur_px, 0.0))) + 2

    def golden(self, rng: np.random.Generator) -> np.ndarray:
        """A frame of the cleared belt: the golden image the locator subtracts."""
        return self.render([], rng)

    def render(self, outlines_mm: list[np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """One frame (uint8, ``(height_px, width_px)``) showing the given silhouettes."""
        h, w = self.shape
        bg = self._background
        cov = None
        rois: list[tuple[int, int, int, int]] = []
        for outline in outlines_mm:
            px = self.calibration.mm_to_px(outline)
            lo = np.floor(px.min(axis=0)).astype(int) - 1
            hi = np.ceil(px.max(axis=0)).astype(int) + 2
            u0, v0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
            u1, v1 = min(int(hi[0]), w), min(int(hi[1]), h)
            if u0 >= u1 or v0 >= v1:
                continue                          # wholly outside the image
            if cov is None:
                cov = np.zeros((h, w), dtype=np.float32)
            local = _coverage(px - np.array([u0, v0]), u1 - u0, v1 - v0)
            np.maximum(cov[v0:v1, u0:u1], local, out=cov[v0:v1, u0:u1])
            rois.append((u0, v0, u1, v1))
        img = bg.copy()
        if cov is not None:
            du, dv = (int(x) for x in rng.integers(0, _TEXTURE_PAD, size=2))
            fg = self._texture[dv:dv + h, du:du + w]
            for u0, v0, u1, v1 in rois:           # overlaps recompute the same values
                c = cov[v0:v1, u0:u1]
                b = bg[v0:v1, u0:u1]
                img[v0:v1, u0:u1] = b - c * (b - fg[v0:v1, u0:u1])
            if self.spec.blur_px > 0:
                img = cv2.GaussianBlur(img, (0, 0), self.spec.blur_px)
        raw = np.frombuffer(rng.bytes(h * w), dtype=np.uint8).reshape(h, w)
        noise = cv2.LUT(raw, self._noise_lut)
        return cv2.add(img, noise, dtype=cv2.CV_8U)


def _coverage(px: np.ndarray, w: int, h: int) -> np.ndarray:
    """Fraction (0..1) of each pixel of a ``w`` x ``h`` box covered by the polygon ``px``.

    Drawn at ``SUPERSAMPLE``x with sub-pixel vertices, then area-averaged. Sub-pixel ``j``
    of the fine grid has its centre at coarse coordinate ``(j - (k-1)/2) / k``.
    """
    k = SUPERSAMPLE
    fine = np.zeros((h * k, w * k), dtype=np.uint8)
    pts = np.round((px * k + (k - 1) / 2.0) * (1 << _SHIFT)).astype(np.int32)
    cv2.fillPoly(fine, [pts.reshape(-1, 1, 2)], 255, lineType=cv2.LINE_8, shift=_SHIFT)
    small = cv2.resize(fine, (w, h), interpolation=cv2.INTER_AREA)
    return small.astype(np.float32) * np.float32(1.0 / 255.0)
