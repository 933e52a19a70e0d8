"""Camera images of the belt, for the simulated cell.

Two lightings (``RenderSpec.lighting``). ``backlit``: a backlight that falls off towards
the corners (vignetting), dark anti-aliased part silhouettes with a little texture.
``frontlit``: no backlight; a dark belt (``belt_grey``) lit from above, light parts
(``part_grey``) whose edges fall off into shade (``shading``) with a specular highlight
(``highlight`` grey levels, saturating) towards the lamp. Both: holes show what is behind
them, optical blur and sensor noise. Parts are drawn through the *truth* calibration, which the simulator may
set apart from the cell's calibration to model a mis-calibrated camera; with a lens and a
tilt in it (``sim.lens_*``, ``sim.tilt_deg``) the outline's vertices go through the true
homography and lens distortion (``vision.calibration.Calibration.mm_to_px``).

Speed (about 1-2 ms a 640x484 frame): the background is precomputed, each part is
supersampled, composited and blurred only in its own box, and the noise is the
generator's raw random bytes through a 256-entry Gaussian look-up table (Gaussian to
±2.9 σ) — ``rng.normal`` alone would cost 4 ms a frame.
"""

from __future__ import annotations

from statistics import NormalDist

import cv2
import numpy as np

from feeder_bt.core.geometry import rings
from feeder_bt.core.model import CameraCalibration, CameraSpec
from feeder_bt.vision.pixels import Calibration

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
        self._front = rs.lighting == "frontlit"
        level = rs.belt_grey if self._front else rs.backlight
        self._background = (level * (1.0 - rs.falloff * r2)).astype(np.float32)
        # the lamp's falloff lights the parts too (a backlight does not reach their top)
        self._light = (1.0 - rs.falloff * r2).astype(np.float32) if self._front else None
        self._mm_per_px = self.calibration.mm_per_px
        # A smooth, fixed texture field for the parts (moulding marks, dust, thickness).
        trng = np.random.default_rng(12345)
        tex = trng.standard_normal((h + _TEXTURE_PAD, w + _TEXTURE_PAD)).astype(np.float32)
        tex = cv2.GaussianBlur(tex, (0, 0), 3.0)
        tex *= _TEXTURE_GREY / max(float(tex.std()), 1e-6)
        self._texture = tex + np.float32(rs.part_grey)
        self._noise_lut = (_gaussian_lut() * np.float32(rs.noise_sigma)).reshape(1, 256)
        self._pad = int(np.ceil(4 * max(rs.blur_px, 0.0))) + 2   # blur margin around parts

    def golden(self, rng: np.random.Generator) -> np.ndarray:
        """A frame of the cleared belt: the golden image the locator subtracts."""
        return self.render([], rng)

    def render(self, outlines_mm: list[np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """One frame (uint8, ``(height_px, width_px)``) showing the given silhouettes.

        Outlines that overlap merge into one silhouette (touching parts). Only boxes around
        the parts are composited and blurred: elsewhere the background is smooth already.
        """
        if len(outlines_mm) < 2:
            return self.render_px([self.calibration.mm_to_px(o) for o in outlines_mm], rng)
        # one mapping for all the outlines (pointwise: the same pixels as one call each,
        # without a call's overhead per part)
        px = self.calibration.mm_to_px(np.concatenate(outlines_mm))
        cuts = np.cumsum([len(o) for o in outlines_mm[:-1]])
        return self.render_px(np.split(px, cuts), rng)

    def render_px(self, outlines_px: list[np.ndarray], rng: np.random.Generator) -> np.ndarray:
        """``render`` of silhouettes given in pixels (a target held off the belt, projected
        by the caller through the true camera)."""
        h, w = self.shape
        p = self._pad
        parts: list[tuple[list[int], list[np.ndarray]]] = []
        for px in outlines_px:                            # NaN rows part a part's rings
            lo, hi = np.nanmin(px, axis=0), np.nanmax(px, axis=0)
            box = [max(int(lo[0]) - p, 0), max(int(lo[1]) - p, 0),
                   min(int(hi[0]) + p + 2, w), min(int(hi[1]) + p + 2, h)]
            if box[0] < box[2] and box[1] < box[3]:      # else wholly outside the image
                parts.append((box, [px]))
        boxes: list[tuple[Box, np.ndarray]] = []
        if parts:
            du, dv = (int(x) for x in rng.integers(0, _TEXTURE_PAD, size=2))
            for (u0, v0, u1, v1), pxs in _merge_boxes(parts):
                cov = _coverage([q - np.array([u0, v0]) for q in pxs], u1 - u0, v1 - v0)
                b = self._background[v0:v1, u0:u1]
                fg = self._texture[dv + v0:dv + v1, du + u0:du + u1]
                if self._front:
                    fg = self._lit(fg, cov, self._light[v0:v1, u0:u1])
                comp = b - cov * (b - fg)
                if self.spec.blur_px > 0:
                    comp = cv2.GaussianBlur(comp, (0, 0), self.spec.blur_px)
                boxes.append(([u0, v0, u1, v1], comp))
        n = h * w
        raw = rng.bit_generator.random_raw((n + 7) // 8).view(np.uint8)[:n].reshape(h, w)
        noise = cv2.LUT(raw, self._noise_lut)
        # The background plus noise, then each box again from its composite: the same sums
        # as compositing into a copy of the background first, without the copy.
        img = cv2.add(self._background, noise, dtype=cv2.CV_8U)
        for (u0, v0, u1, v1), comp in boxes:    # later boxes over earlier, as before
            img[v0:v1, u0:u1] = cv2.add(comp, noise[v0:v1, u0:u1], dtype=cv2.CV_8U)
        return img


    def _lit(self, fg: np.ndarray, cov: np.ndarray, light: np.ndarray) -> np.ndarray:
        """Front light on the parts of one box: brightest on the top surface, falling off by
        ``shading`` towards the edges (over ``_BEVEL_MM``), plus a highlight where the
        surface faces the lamp (half-way from the middle of each part to its edge)."""
        rs = self.spec
        inside = (cov > 0.5).astype(np.uint8)
        dist = cv2.distanceTransform(inside, cv2.DIST_L2, 3) * np.float32(self._mm_per_px)
        flat = np.minimum(dist * np.float32(1.0 / _BEVEL_MM), 1.0)
        shade = np.float32(1.0 - rs.shading) + np.float32(rs.shading) * flat
        out = fg * shade * light
        if rs.highlight > 0:
            # a ridge of light at a fixed depth inside each outline (a rounded edge or a
            # chamfer catching the lamp)
            ridge = np.exp(-((dist - np.float32(_HIGHLIGHT_MM)) ** 2)
                           * np.float32(1.0 / (2 * _HIGHLIGHT_WIDTH_MM ** 2)))
            out += np.float32(rs.highlight) * ridge * (inside > 0)
        return out


Box = list[int]
_BEVEL_MM = 2.5                      # front light: the edge's shaded band
_HIGHLIGHT_MM = 3.5                  # front light: the highlight ridge, this far inside
_HIGHLIGHT_WIDTH_MM = 0.8


def _merge_boxes(parts: list[tuple[Box, list[np.ndarray]]]) -> list[tuple[Box, list[np.ndarray]]]:
    """Union overlapping ``[u0, v0, u1, v1]`` boxes (and their outlines) until none overlap."""
    out: list[tuple[Box, list[np.ndarray]]] = []
    for box, pxs in parts:
        box, pxs = list(box), list(pxs)
        merged = True
        while merged:
            merged = False
            for other in out:
                ob = other[0]
                if box[0] < ob[2] and ob[0] < box[2] and box[1] < ob[3] and ob[1] < box[3]:
                    out.remove(other)
                    box = [min(box[0], ob[0]), min(box[1], ob[1]),
                           max(box[2], ob[2]), max(box[3], ob[3])]
                    pxs += other[1]
                    merged = True
                    break
        out.append((box, pxs))
    return out


def _coverage(polys_px: list[np.ndarray], w: int, h: int) -> np.ndarray:
    """Fraction (0..1) of each pixel of a ``w`` x ``h`` box covered by the polygons' union.

    Drawn at ``SUPERSAMPLE``x with sub-pixel vertices, then area-averaged. Sub-pixel ``j``
    of the fine grid has its centre at coarse coordinate ``(j - (k-1)/2) / k``.
    """
    k = SUPERSAMPLE
    fine = np.zeros((h * k, w * k), dtype=np.uint8)
    for px in polys_px:
        # one call per part: a union of parts; within a part, its rings (the outer one and
        # its holes, parted by NaN rows) fill even-odd, so the holes stay empty
        pts = np.round((px * k + (k - 1) / 2.0) * (1 << _SHIFT))
        cv2.fillPoly(fine, [r.astype(np.int32).reshape(-1, 1, 2) for r in rings(pts)], 255,
                     lineType=cv2.LINE_8, shift=_SHIFT)
    small = cv2.resize(fine, (w, h), interpolation=cv2.INTER_AREA)
    return np.multiply(small, np.float32(1.0 / 255.0), dtype=np.float32)
