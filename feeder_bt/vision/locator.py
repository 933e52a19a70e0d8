"""The OpenCV locator: pixels in, part poses in the belt frame out.

It sees only the grey image, the golden image, the recipe and the cell's calibration —
never the simulator's truth. Pipeline: golden-image subtraction, threshold, morphology,
external contours; blobs on the image border wait for the next frame; features are
measured in mm through the calibration; a blob is the first recipe class whose feature
ranges all contain it, otherwise it is rejected (two touching parts make one blob that fits
no class). Position is the grey-level centroid of the blob; orientation comes from the
recipe's method (``cut_corner``: the square's uneven cut corner also tells its face).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..geometry import shape_outline, wrap_deg
from ..scenario.model import PartSpec, VisionClass, VisionRecipe
from .calibration import Calibration

GRID_MM = 0.5                 # raster step for matching an outline against a blob
NOISE_PX = 12                 # blobs smaller than this are not even reported as rejected


@dataclass
class Detection:
    part: str | None
    pose: str | None
    pickable: bool
    x_mm: float
    y_mm: float
    angle_deg: float
    u_px: float
    v_px: float
    features: dict[str, float] = field(default_factory=dict)
    reason: str = ""                       # empty when accepted, else why rejected


@dataclass
class LocateResult:
    parts: list[Detection]
    rejected: list[Detection]
    ms: float = 0.0


class Locator:
    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec],
                 calibration: Calibration) -> None:
        self.recipe, self.parts, self.cal = recipe, parts, calibration
        self.golden: np.ndarray | None = None
        m = recipe.morphology
        self._open = _kernel(m.open_px)
        self._close = _kernel(m.close_px)
        self._min_area_px = recipe.min_area_mm2 / calibration.mm2_per_px2
        self._models = {name: shape_outline(p.shape) for name, p in parts.items()}

    def set_golden(self, image: np.ndarray) -> None:
        """The empty, lit belt: subtracted from every frame, uneven backlight and all."""
        self.golden = cv2.GaussianBlur(image, (0, 0), 1.0)

    # ------------------------------------------------------------------ pipeline
    def foreground(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(difference image, binary mask): dark parts on a bright backlight become bright."""
        if self.recipe.golden_image and self.golden is not None:
            diff = cv2.subtract(self.golden, image)
        else:
            diff = cv2.bitwise_not(image)
        th = self.recipe.threshold
        if th.method == "otsu":
            _, mask = cv2.threshold(diff, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        elif th.method == "adaptive":
            mask = cv2.adaptiveThreshold(diff, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                         cv2.THRESH_BINARY, int(th.block_px) | 1, -th.c)
        else:
            _, mask = cv2.threshold(diff, th.value, 255, cv2.THRESH_BINARY)
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        return diff, mask

    def locate(self, image: np.ndarray) -> LocateResult:
        diff, mask = self.foreground(image)
        h, w = mask.shape
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        found: list[Detection] = []
        rejected: list[Detection] = []
        for contour in contours:
            area_px = cv2.contourArea(contour)
            if area_px < NOISE_PX:
                continue
            bx, by, bw, bh = cv2.boundingRect(contour)
            det = self._measure(contour, diff, mask, (bx, by, bw, bh))
            if bx <= 0 or by <= 0 or bx + bw >= w or by + bh >= h:
                det.reason = "touches the image border"
            elif det.features["area_mm2"] < self.recipe.min_area_mm2:
                det.reason = "too small"
            else:
                self._classify(det, contour)
            (rejected if det.reason else found).append(det)
        return LocateResult(found, rejected)

    # ------------------------------------------------------------------ measuring
    def _measure(self, contour: np.ndarray, diff: np.ndarray, mask: np.ndarray,
                 box: tuple[int, int, int, int]) -> Detection:
        bx, by, bw, bh = box
        # grey-level centroid over the blob (grown by a pixel so the soft edge counts)
        roi_mask = np.zeros((bh + 4, bw + 4), np.uint8)
        cv2.drawContours(roi_mask, [contour - np.array([bx - 2, by - 2])], -1, 255,
                         thickness=cv2.FILLED)
        roi_mask = cv2.dilate(roi_mask, _kernel(3))
        y0, x0 = by - 2, bx - 2
        ys, xs = slice(max(y0, 0), y0 + bh + 4), slice(max(x0, 0), x0 + bw + 4)
        sub = diff[ys, xs].astype(np.float32)
        sm = roi_mask[ys.start - y0:ys.start - y0 + sub.shape[0],
                      xs.start - x0:xs.start - x0 + sub.shape[1]]
        weight = np.where(sm > 0, sub, 0.0)
        mom = cv2.moments(weight)
        if mom["m00"] > 0:
            u = xs.start + mom["m10"] / mom["m00"]
            v = ys.start + mom["m01"] / mom["m00"]
        else:
            cm = cv2.moments(contour)
            u, v = cm["m10"] / max(cm["m00"], 1e-9), cm["m01"] / max(cm["m00"], 1e-9)
        x, y = (float(c) for c in self.cal.px_to_mm(np.array([[u, v]]))[0])

        pts = self.cal.px_to_mm(contour.reshape(-1, 2).astype(float)).astype(np.float32)
        pixels = float(cv2.countNonZero(mask[by:by + bh, bx:bx + bw] &
                                        roi_mask[2:2 + bh, 2:2 + bw]))
        area = pixels * self.cal.mm2_per_px2
        perimeter = float(cv2.arcLength(_smooth(pts), True))
        (_, _), (rw, rh), _ = cv2.minAreaRect(pts)
        hull_area = float(cv2.contourArea(cv2.convexHull(pts)))
        poly_area = float(cv2.contourArea(pts))
        hu = cv2.HuMoments(cv2.moments(pts)).flatten()
        feats = {
            "area_mm2": area,
            "perimeter_mm": perimeter,
            "circularity": 4 * math.pi * area / max(perimeter * perimeter, 1e-9),
            "aspect": max(rw, rh) / max(min(rw, rh), 1e-9),
            "rectangularity": poly_area / max(rw * rh, 1e-9),
            "solidity": poly_area / max(hull_area, 1e-9),
            "hu1": float(hu[0]),
            "hu2": float(hu[1]),
        }
        return Detection(None, None, False, x, y, 0.0, float(u), float(v), feats)

    # ------------------------------------------------------------------ classifying
    def _classify(self, det: Detection, contour: np.ndarray) -> None:
        candidates = [c for c in self.recipe.classes if _in_ranges(c, det.features)]
        if not candidates:
            det.reason = "fits no class (touching parts?)"
            return
        method = self.recipe.orientation
        cls = candidates[0]
        if method == "cut_corner" and any(c.mirrored is not None for c in candidates):
            chiral = [c for c in candidates if c.mirrored is not None]
            angle, mirrored, score = self._match_outline(contour, det, chiral[0].part)
            det.features["mirrored"] = 1.0 if mirrored else 0.0
            det.features["match"] = score
            det.angle_deg = angle
            same_face = [c for c in candidates if c.mirrored is None or c.mirrored == mirrored]
            if not same_face:
                det.reason = "fits no class for the face it shows"
                return
            cls = same_face[0]
        elif method == "principal_axis":
            det.angle_deg = self._principal_axis(contour)
        det.part, det.pose, det.pickable = cls.part, cls.pose, cls.pickable

    def _principal_axis(self, contour: np.ndarray) -> float:
        pts = self.cal.px_to_mm(contour.reshape(-1, 2).astype(float)).astype(np.float32)
        m = cv2.moments(pts)
        return math.degrees(0.5 * math.atan2(2 * m["mu11"], m["mu20"] - m["mu02"]))

    def _match_outline(self, contour: np.ndarray, det: Detection,
                       part: str) -> tuple[float, bool, float]:
        """Angle and face of a chiral outline.

        For each face, try the four right-angle turns of the minimum-area rectangle's angle
        and refine the best by a short search (overlap of rasterised outlines). The face is
        then decided only where the two fitted outlines differ — around the uneven cut — so
        the rest of the outline cannot drown the evidence."""
        model = self._models[part]
        pts = self.cal.px_to_mm(contour.reshape(-1, 2).astype(float)) - [det.x_mm, det.y_mm]
        (_, _), (_, _), rect_angle = cv2.minAreaRect(pts.astype(np.float32))
        reach = float(np.sqrt((model ** 2).sum(axis=1)).max() * 1.15)
        size = int(2 * reach / GRID_MM) + 1
        blob = _raster(pts, reach, size)
        fits = []
        for mirrored in (False, True):
            base = model * np.array([1.0, -1.0]) if mirrored else model
            theta, score = max(((rect_angle + 90.0 * k,
                                 _iou(blob, _raster(_rotate(base, rect_angle + 90.0 * k),
                                                    reach, size))) for k in range(4)),
                               key=lambda ts: ts[1])
            for step in (1.0, 0.5):
                for d in (-step, step):
                    s = _iou(blob, _raster(_rotate(base, theta + d), reach, size))
                    if s > score:
                        theta, score = theta + d, s
            fits.append((theta, score, _raster(_rotate(base, theta), reach, size)))
        (t_up, s_up, r_up), (t_dn, s_dn, r_dn) = fits
        only_up, only_dn = r_up & (1 - r_dn), r_dn & (1 - r_up)
        cov_up = np.count_nonzero(blob & only_up) / max(np.count_nonzero(only_up), 1)
        cov_dn = np.count_nonzero(blob & only_dn) / max(np.count_nonzero(only_dn), 1)
        if cov_dn > cov_up:
            return wrap_deg(t_dn), True, s_dn
        return wrap_deg(t_up), False, s_up

    # ------------------------------------------------------------------ drawing
    def annotate(self, image: np.ndarray, result: LocateResult) -> np.ndarray:
        """A colour copy of the frame with what the locator found and rejected, and why."""
        out = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        _, mask = self.foreground(image)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(out, contours, -1, (160, 160, 160), 1)
        for det in result.parts:
            colour = (0, 200, 0) if det.pickable else (0, 200, 220)
            c = (int(round(det.u_px)), int(round(det.v_px)))
            cv2.circle(out, c, 3, colour, -1)
            tip = self.cal.mm_to_px(np.array([[det.x_mm + 20 * math.cos(math.radians(
                det.angle_deg)), det.y_mm + 20 * math.sin(math.radians(det.angle_deg))]]))[0]
            cv2.arrowedLine(out, c, (int(tip[0]), int(tip[1])), colour, 1, tipLength=0.3)
            cv2.putText(out, f"{det.part}/{det.pose}", (c[0] + 5, c[1] - 5),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.35, colour, 1)
        for det in result.rejected:
            c = (int(round(det.u_px)), int(round(det.v_px)))
            cv2.drawMarker(out, c, (0, 0, 230), cv2.MARKER_TILTED_CROSS, 8, 1)
            cv2.putText(out, det.reason, (c[0] + 5, c[1] + 12), cv2.FONT_HERSHEY_SIMPLEX,
                        0.35, (0, 0, 230), 1)
        return out


def _in_ranges(cls: VisionClass, feats: dict[str, float]) -> bool:
    return all(lo <= feats[name] <= hi for name, (lo, hi) in cls.ranges.items())


def _kernel(size: int) -> np.ndarray | None:
    if size <= 1:
        return None
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (size, size))


def _smooth(pts: np.ndarray) -> np.ndarray:
    """A pixel contour's staircase makes its length too long; a light polygon fit doesn't."""
    return cv2.approxPolyDP(pts.reshape(-1, 1, 2), 0.5, True)


def _rotate(pts: np.ndarray, deg: float) -> np.ndarray:
    a = math.radians(deg)
    c, s = math.cos(a), math.sin(a)
    return pts @ np.array([[c, -s], [s, c]]).T


def _raster(pts: np.ndarray, reach: float, size: int) -> np.ndarray:
    img = np.zeros((size, size), np.uint8)
    grid = np.round(((pts + reach) / GRID_MM) * 16).astype(np.int32)
    cv2.fillPoly(img, [grid.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=4)
    return img


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = int(np.count_nonzero(a & b))
    union = int(np.count_nonzero(a | b))
    return inter / union if union else 0.0
