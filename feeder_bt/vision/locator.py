"""The OpenCV locator: a grey image -> poses of singulated parts in the belt frame.

It sees only pixels, the cell's calibration and the recipe — never ground truth.
Pipeline: the image in which parts are bright (``foreground: dark``: the golden image minus
the frame, or the inverted frame; ``light``: the frame minus the golden image, or the
frame), threshold, morphology, external contours (with their holes, ``RETR_CCOMP``, when a
class ranges over ``holes`` or ``hole_area_mm2``); blobs touching the image border or
smaller than ``min_area_mm2`` are rejected; features (``FEATURES``) are measured in mm (mm² for areas) through the
calibration, corrected for pixelisation so that they are close to the physical value (a
50.8 mm disc: ~2030 mm², circularity ~0.99); the first recipe class whose ranges all hold
names the part and pose. Position is the blob's area centroid with its holes taken out
(found whenever a class's outline has holes), which is the part frame's origin
(``geometry``). The image work (difference image, threshold, morphology, contours)
is ``segment.Segmenter``'s, of which ``Locator`` is one; the blobs and their features are
measured in ``blobs``; the cut-corner face and angle in ``corners``.
Merged (touching) parts fall outside every class and are rejected, so they are never
picked; a blob that fits no class is rejected with the class nearest it by area and the
first of that class's ranges it is outside (``Locator._no_class``).

Features are measured as a cascade, cheapest first (``features.GROUPS``): every blob gets
its area and centroid from the contour's moments; a class's other features are measured
only when the blob is checked against that class and its cheaper ranges held. So a
``Detection``'s ``features`` hold ``area_mm2`` plus the features its checks needed (and
``mirrored`` once a face was looked at) — a flat lens has area, perimeter and circularity,
a blob rejected as too big only its area. ``locate(..., all_features=True)`` and
``measure_blobs`` measure every feature of every blob, for tools that show or tune them.

Recipe semantics worth knowing:

* ``threshold.method``: ``fixed`` (``value`` grey levels of difference), ``otsu`` (Otsu's
  level, but never below ``value``, so an empty belt does not turn noise into blobs), or
  ``adaptive`` (``block_px``; foreground above the local mean minus ``c``: OpenCV's
  ``C``, so ``c`` < 0).
* ``orientation`` (the recipe's, or a class's own): ``none`` -> 0; ``principal_axis`` ->
  the long axis from moments, in (-90, 90]; ``cut_corner`` -> for classes with
  ``mirrored`` set, the angle (and face) at which the part's ``face_up`` outline matches
  the blob, in (-180, 180]; other classes fall back to the principal axis when elongated,
  else 0. The face and angle are read from the blob's outline to a fraction of a pixel
  (``Locator._faces``). ``outline`` -> the class's own outline (its pose's silhouette,
  holes and all) matched against the blob (``vision.outline``); ``moment`` -> the long
  axis turned to the heavier end (the third moment: a screw's head).

* ``rulers``: gauges on the outline from the centroid (``vision.rulers``): a line's width
  or a circle's arcs, checked after every feature of a class (they cost the most).

Each call of ``locate`` uses only local state and per-thread scratch images (the golden
image is read, never written), so one ``Locator`` may serve several threads.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from feeder_bt.core.geometry import pose_outline, rings, wrap_deg
from feeder_bt.core.model import PartSpec, VisionClass, VisionRecipe
from feeder_bt.vision.blobs import (
    Blob,
    Detection,
    _hull_stats,
    contour_mm,
    find_blobs,
    measure_feature,
    principal_angle,
)
from feeder_bt.vision.clearance import offer_grips
from feeder_bt.vision.corners import (
    _CornerSignature,
    _cut_corner,
    _orient,
    _part_signature,
    _signature_rows,
)
from feeder_bt.vision.features import FEATURES, GROUP_OF
from feeder_bt.vision.jit import kernels, warm
from feeder_bt.vision.outline import MomentModel, OutlineModel, orient_moment, orient_outline
from feeder_bt.vision.overlay import draw
from feeder_bt.vision.pixels import Calibration, PixelGrid
from feeder_bt.vision.rulers import measure as measure_ruler
from feeder_bt.vision.segment import Segmenter, to_grey
from feeder_bt.vision.split import H_SHARE, inscribed_px, split_blob

_ELONGATED = 1.3               # aspect above which a symmetric blob has a principal axis


@dataclass
class LocateResult:
    """What ``Locator.locate`` found in one frame: accepted parts, rejected blobs, time."""

    parts: list[Detection]
    rejected: list[Detection]
    ms: float
    blobs: list[Blob] = field(default_factory=list, repr=False)   # parts + rejected
    # the (part, pose) classes whose angle means something (a class that reads one, of a
    # part not alike at every turn): the drawing puts an arrow on those only
    angled: frozenset[tuple[str, str]] | None = field(default=None, repr=False)

    @property
    def contours(self) -> list[np.ndarray]:
        """The blobs' contours (px), for drawing: made only when asked for."""
        return [b.contour for b in self.blobs]


# ---------------------------------------------------------------------------- locator


class Locator(Segmenter):
    """Finds parts in images with one recipe; see the module docstring."""

    def __init__(self, recipe: VisionRecipe, parts: dict[str, PartSpec],
                 calibration: Calibration) -> None:
        self.parts = parts
        self.calibration = calibration
        for cls in recipe.classes:
            for name in cls.ranges:
                if name not in FEATURES:
                    raise ValueError(f"class {cls.part}/{cls.pose}: unknown feature {name!r}")
            for name in cls.rulers:
                if name not in recipe.rulers:
                    raise ValueError(f"class {cls.part}/{cls.pose}: unknown ruler {name!r}")
        # each class's ranges, cheapest feature first, its rulers last: the cascade's order
        # of checks (a ruler's reading is kept among the blob's features, by its name)
        self._checks: list[tuple[VisionClass, list[tuple[str, float, float]]]] = [
            (cls, sorted(((n, lo, hi) for n, (lo, hi) in cls.ranges.items()),
                         key=lambda r: GROUP_OF[r[0]])
             + [(n, lo, hi) for n, (lo, hi) in cls.rulers.items()])
            for cls in recipe.classes]
        # The smoothed perimeter reads every boundary pixel of the contour; without it only
        # the chain's corners are kept (the same polygon: the same moments, hull and
        # rectangle, fewer points to trace and sum). The face reads only the hull, but
        # counting a corner chain's boundary pixels costs more than tracing them all.
        # each class's orientation: its own, else the recipe's
        self._modes = [cls.orientation or recipe.orientation for cls in recipe.classes]
        chiral_cut = any(m == "cut_corner" and cls.mirrored is not None
                         for cls, m in zip(recipe.classes, self._modes, strict=True))
        self._full_chain = any(GROUP_OF[n] == GROUP_OF["perimeter_mm"]
                               for cls in recipe.classes for n in cls.ranges) or chiral_cut
        # hole contours are searched for only when a class ranges over them, or a class's
        # outline has holes: its point is the area centroid with them taken out (the part
        # frame's origin), which the filled outline's is not
        self._want_holes = any(GROUP_OF[n] == GROUP_OF["holes"]
                               for cls in recipe.classes for n in cls.ranges) or any(
            cls.part in parts and cls.pose in parts[cls.part].poses
            and len(rings(pose_outline(parts[cls.part], cls.pose))) > 1
            for cls in recipe.classes)
        # What most blobs will be asked for, measured for all of a frame's blobs in one
        # compiled pass (``find_blobs``): the features the first class ranges over (every
        # blob of its size is checked against it), and the hull where faces are read. Others
        # are measured a blob at a time, when asked for (a lens on edge: its rectangle).
        first = {GROUP_OF[n] for n in recipe.classes[0].ranges} if recipe.classes else set()
        self._want_length = GROUP_OF["perimeter_mm"] in first
        self._want_hulls = bool({GROUP_OF["aspect"], GROUP_OF["solidity"]} & first) or \
            chiral_cut
        warm()                  # the compiled per-blob work: loaded now, not on a frame
        self._signatures: dict[str, _CornerSignature] = {}
        for cls, mode in zip(recipe.classes, self._modes, strict=True):
            if mode != "cut_corner" or cls.mirrored is None or cls.part in self._signatures:
                continue
            sig = _part_signature(parts[cls.part])
            if sig is None:
                raise ValueError(f"part {cls.part}: no cut corner to orient by")
            self._signatures[cls.part] = sig
        # orientation outline / moment: each class matched against its own pose's outline
        # (vision.outline), one model per outline shown; the key names it in Blob.oriented
        self._models: dict[str, OutlineModel | MomentModel] = {}
        keys: list[str | None] = []
        for cls, mode in zip(recipe.classes, self._modes, strict=True):
            part = parts.get(cls.part)
            if mode not in ("outline", "moment") or part is None or cls.pose not in part.poses:
                keys.append(None)
                continue
            if mode == "outline":      # face up and down of one silhouette: one model
                own = part.poses[cls.pose].silhouette is not None
                key = f"outline:{cls.part}:{cls.pose if own else ''}"
                if key not in self._models:
                    self._models[key] = OutlineModel(part, cls.pose, recipe.outline_match)
            else:
                key = f"moment:{cls.part}:{cls.pose}"
                if key not in self._models:
                    self._models[key] = MomentModel(part, cls.pose)
            keys.append(key)
        self._angled = frozenset(
            (cls.part, cls.pose) for cls, mode in zip(recipe.classes, self._modes, strict=True)
            if mode != "none" and cls.part in parts
            and parts[cls.part].period_deg > 2 * parts[cls.part].orientation_tolerance_deg)
        self._picks = any(parts[cls.part].pick is not None for cls in recipe.classes
                          if cls.part in parts)
        self._clearance = recipe.check_clearance
        # what ``_classify`` needs of each class, looked up once: its checks, its
        # orientation and how its angle or face is told (an outline or moment model's key,
        # a cut-corner signature, or neither)
        self._plan = [(cls, checks, mode, key,
                       self._signatures.get(cls.part) if mode == "cut_corner" else None)
                      for (cls, checks), mode, key
                      in zip(self._checks, self._modes, keys, strict=True)]
        self._grids: dict[tuple[int, int], PixelGrid] = {}    # image size -> its table
        # split_touching: a part's dome of the distance transform rises about its inscribed
        # radius; a marker is a dome that stands a share of the smallest (pickable) part's
        # above its saddles (vision.split). A blob at the frame's edge is cut only if it
        # is at least half as big again as the smallest class's least area: a part cut by
        # the edge is smaller, a clump of two is not
        self._split_h: float | None = None
        self._split_border_mm2 = math.inf
        if recipe.split_touching:
            named = [c for c in recipe.classes
                     if c.part in parts and c.pose in parts[c.part].poses]
            sizes = [inscribed_px(pose_outline(parts[c.part], c.pose), calibration.mm_per_px)
                     for c in (([c for c in named if c.pickable]) or named)]
            self._split_h = H_SHARE * min(sizes) if sizes else None
            lows = [c.ranges["area_mm2"][0] for c in named if "area_mm2" in c.ranges]
            self._split_border_mm2 = 1.5 * min(lows) if lows else 0.0
        if recipe.rulers:              # without rulers the cascade keeps its plain lookup
            self._feature = self._feature_or_ruler            # type: ignore[method-assign]
        super().__init__(recipe)       # the segmentation, once the classes are known good

    # -------------------------------------------------------------- locate

    def locate(self, image: np.ndarray, all_features: bool = False) -> LocateResult:
        """Find, measure and classify every blob in ``image``.

        ``all_features``: measure every feature of every blob (for tools that show them),
        not only those the cascade needed (see the module docstring).
        """
        t0 = time.perf_counter()
        img = to_grey(image)
        full = all_features or self._full_chain
        contours, holes, diff, level = self._segment(img, full,
                                                     all_features or self._want_holes)
        blobs = self._blobs(contours, img.shape[:2], all_features, full=full, holes=holes,
                            grey=img)
        # classes first; the blobs that need a face wait for one batch of fine outlines
        waiting = [b for b in blobs if not b.det.reason and not self._classify(b)]
        if waiting:
            self._faces(waiting, img, diff, level)
            for b in waiting:
                self._classify(b)
        if self.recipe.split_touching:
            blobs = self._split(blobs, img, diff, level)
        if self._picks:
            offer_grips(blobs, self.parts, self.calibration,   # gripper clearance
                        check=self._clearance)
        parts: list[Detection] = []
        rejected: list[Detection] = []
        for b in blobs:
            (rejected if b.det.reason else parts).append(b.det)
        ms = (time.perf_counter() - t0) * 1e3
        return LocateResult(parts=parts, rejected=rejected, ms=ms, blobs=blobs,
                            angled=self._angled)

    def measure_blobs(self, image: np.ndarray) -> list[Detection]:
        """Every blob's features, unclassified, measured exactly as ``locate`` measures them
        (all of ``FEATURES``, as with ``all_features``).

        For tools that tune a recipe (``feeder recipe suggest``): one feature extractor for
        tuning and feeding. ``reason`` marks blobs ``locate`` would reject before
        classification ("touches border", "too small"); ``part`` is always None.
        """
        img = to_grey(image)
        contours, holes = self._segment(img, True, True)[:2]
        blobs = self._blobs(contours, img.shape[:2], all_features=True, full=True, holes=holes,
                            grey=img)
        return [b.det for b in blobs]

    def _split(self, blobs: list[Blob], img: np.ndarray, diff: np.ndarray | None,
               level: float | None) -> list[Blob]:
        """``split_touching``: each blob that fits no class, or a clump touching the frame's
        edge, cut into pieces (``vision.split``); if every piece is a part or touches the
        edge, and one at least is a part, the pieces replace it."""
        out: list[Blob] = []
        for b in blobs:
            reason = b.det.reason
            if not (reason.startswith("no class") or (
                    reason == "touches border"
                    and b.det.features["area_mm2"] >= self._split_border_mm2)):
                out.append(b)
                continue
            pieces = split_blob(b, self._split_h, img.shape[:2])
            new = find_blobs([c for c, _ in pieces], img.shape[:2], self.calibration,
                             self.recipe.min_area_mm2, full=True,
                             holes=[hs for _, hs in pieces],
                             mapping=self._mapping(img.shape[:2]),
                             length=self._want_length, hulls=self._want_hulls,
                             min_hole_mm2=self.recipe.min_hole_mm2, grey=img) \
                if pieces else []
            waiting = [p for p in new if not p.det.reason and not self._classify(p)]
            if waiting:
                self._faces(waiting, img, diff, level)
                for p in waiting:
                    self._classify(p)
            if any(not p.det.reason for p in new) and all(
                    not p.det.reason or p.det.reason == "touches border" for p in new):
                for p in new:
                    p.det.features["split"] = 1.0
                out += new
            else:
                out.append(b)
        return out

    # -------------------------------------------------------------- per blob

    def _blobs(self, contours: list[np.ndarray], shape: tuple[int, int], all_features: bool,
               full: bool = True, holes: list[list[np.ndarray]] | None = None,
               grey: np.ndarray | None = None) -> list[Blob]:
        """The contours worth reporting, measured as far as every blob is (``find_blobs``);
        with ``all_features`` every feature of every blob, the rejected ones too."""
        mapping = self._mapping(shape)
        blobs = find_blobs(contours, shape, self.calibration, self.recipe.min_area_mm2,
                           full=full, holes=holes, mapping=mapping,
                           length=all_features or self._want_length,
                           hulls=all_features or self._want_hulls,
                           min_hole_mm2=self.recipe.min_hole_mm2, grey=grey)
        if all_features:
            for b in blobs:
                for name in (*FEATURES, *self.recipe.rulers):
                    self._feature(b, name)
        if self.recipe.orientation == "principal_axis":
            for b in blobs:            # as before the cascade: the rejected ones' too
                b.det.angle_deg = principal_angle(cv2.moments(contour_mm(b, mapping)))
        return blobs

    def _feature(self, b: Blob, name: str) -> float:
        """One feature of the blob (``blobs.measure_feature``), measured once."""
        return measure_feature(b, name, self.calibration, self.recipe.min_hole_mm2)

    def _feature_or_ruler(self, b: Blob, name: str) -> float:
        """``_feature``, or one of the recipe's rulers' readings (``vision.rulers``): all
        of them at once, on one mapped outline; ``_feature`` itself for a recipe with
        rulers."""
        rulers = self.recipe.rulers
        if name not in rulers:
            return measure_feature(b, name, self.calibration, self.recipe.min_hole_mm2)
        feats = b.det.features
        if name not in feats:
            mm = contour_mm(b, self.calibration)
            axis = principal_angle(cv2.moments(mm))
            outline = mm.astype(np.float64)
            for n, ruler in rulers.items():
                feats[n] = measure_ruler(ruler, outline, (b.det.x_mm, b.det.y_mm), axis,
                                         b.scale or self.calibration.mm_per_px)
        return feats[name]

    def _faces(self, blobs: list[Blob], img: np.ndarray, diff: np.ndarray | None,
               level: float | None) -> None:
        """Measure each blob's cut-corner signature (``Blob.face``) on its outline to a
        fraction of a pixel (``Segmenter._bright_source``), all of a frame's blobs in one
        compiled call (``kernels.faces``).

        The signature reads only the outline's convex hull, so only the pixel hull's
        vertices (the rectangularity's, ``kernels.blob_stats``: a sixth of the boundary pixels)
        are moved to where the edge crosses the level. On the bench's frames of squares
        (benchmarks/vision_bench.py, 441 parts) the angle's error against the truth is the
        same as from every boundary pixel (mean 0.13°, 95 % under 0.30°; max 0.52° against
        0.41°), every face the same, in two thirds of the time (docs/performance.md). Over
        a part the mapping is affine to a few hundredths of a mm, so the mapped points'
        hull is the mapped hull.
        """
        k = kernels()
        for b in blobs:
            _hull_stats(b)              # measured with the frame's blobs unless not asked
        src, golden, mode = self._bright_source(img, diff)
        kind, cells, par = self._mapping(img.shape[:2])._kernel_table()
        fine = level is not None
        cut = math.floor(level) if fine else 0    # THRESH_BINARY: value > floor(level) is in
        frames = {id(b.frame): b.frame for b in blobs}
        for key, fr in frames.items():
            mine = [b for b in blobs if id(b.frame) == key]
            rows = k.faces(fr.pts, fr.hull, fr.hull_ends,
                           np.array([b.index for b in mine], dtype=np.int64), src, golden,
                           mode, img.shape[1], cut, fine, kind, cells, par)
            for b, sig in zip(mine, _signature_rows(rows), strict=True):
                b.face, b.faced = sig, True

    def prepare(self, shape: tuple[int, int]) -> None:
        """Make the pixel table for frames of ``shape`` (rows, columns) now, before the cell
        ticks: built on first use it took 12 ms of the tick that set the golden image (a
        distorted camera's table), past a 200 Hz tick's 5 ms."""
        self._mapping(tuple(shape))

    def set_golden(self, image: np.ndarray) -> None:
        """The cleared belt; and the pixel table for frames of its size, if ``prepare`` did
        not make it, so that no frame's vision time pays for it."""
        super().set_golden(image)
        self._mapping(np.asarray(image).shape[:2])

    def _mapping(self, shape: tuple[int, int]) -> Calibration | PixelGrid:
        """Where this image size's pixels are mapped to mm: the calibration itself when it
        is a similarity (a matrix product), else its ``PixelGrid`` for the size (built on
        the first frame of that size; two threads may both build it, harmlessly)."""
        cal = self.calibration
        if cal.linear:
            return cal
        grid = self._grids.get(shape)
        if grid is None:
            grid = self._grids[shape] = PixelGrid(cal, tuple(shape))
        return grid

    def _classify(self, b: Blob) -> bool:
        """First class whose ranges (and face, for chiral parts) fit; else a reason. False
        (nothing decided) if a chiral class fits but the blob's face is not measured yet:
        ``_faces`` measures it, then this runs again.

        Classes are tried in the recipe's order, each range cheapest first, so a feature
        is measured only when a class still fits without it.
        """
        det = b.det
        feats = det.features
        chosen: VisionClass | None = None
        looked = False                       # a face was asked for
        why = ""                             # the outline match's reason, if it failed
        for cls, checks, mode, key, model in self._plan:
            for name, lo, hi in checks:      # the ranges, cheapest feature first
                v = feats.get(name)
                if v is None:
                    v = self._feature(b, name)
                if not lo <= v <= hi:
                    break
            else:
                if key is not None:          # outline or moment
                    looked = True
                    oriented = b.oriented.get(key, False)
                    if oriented is False:
                        oriented = b.oriented[key] = self._orient_by(b, key)
                    if isinstance(oriented, str):
                        why = oriented
                        continue
                    angle, mirrored = oriented
                    if mode == "outline":
                        feats["mirrored"] = 1.0 if mirrored else 0.0
                    if cls.mirrored is None or mode == "moment" or mirrored == cls.mirrored:
                        chosen = cls
                        det.angle_deg = angle
                        break
                    continue
                if cls.mirrored is None or model is None:
                    # no face to tell, or no way to tell it: trust the class
                    chosen = cls
                    det.angle_deg = self._symmetric_angle(b, mode)
                    break
                if not b.faced:
                    return False
                looked = True
                oriented = b.oriented.get(cls.part, False)
                if oriented is False:
                    oriented = b.oriented[cls.part] = _orient(model, b.face)
                if oriented is None:
                    continue
                angle, mirrored = oriented
                feats["mirrored"] = 1.0 if mirrored else 0.0
                if mirrored == cls.mirrored:
                    chosen = cls
                    det.angle_deg = angle
                    break
        if chosen is None:
            det.reason = (f"no class ({why})" if why else "no class (face)") if looked \
                else self._no_class(b)
        else:
            det.part, det.pose, det.pickable = chosen.part, chosen.pose, chosen.pickable
            # a symmetric part's angle is defined modulo its period (``PartSpec.symmetry``)
            det.angle_deg = wrap_deg(det.angle_deg, self.parts[chosen.part].period_deg)
        return True

    def _orient_by(self, b: Blob, key: str) -> tuple[float, bool] | str:
        """The blob's angle and face by the outline or moment model ``key``, or why not:
        read on its outline and its holes (of at least ``min_hole_mm2``), in mm."""
        model = self._models[key]
        cal = self.calibration
        holes: list[np.ndarray] = []
        if b.holes:
            px2 = self.recipe.min_hole_mm2 / (b.scale or cal.mm_per_px) ** 2
            holes = [cal.px_to_mm(h.reshape(-1, 2)) for h in b.holes
                     if abs(cv2.contourArea(h)) >= 0.5 * px2]
        xy = contour_mm(b, cal)
        if isinstance(model, MomentModel):
            return orient_moment(model, xy, holes)
        return orient_outline(model, xy, (b.det.x_mm, b.det.y_mm), b.scale or cal.mm_per_px,
                              holes)

    def _no_class(self, b: Blob) -> str:
        """Why a blob fits no class: the class nearest it by area and the first of that
        class's ranges it is outside (already measured: the cascade stopped there)."""
        if not self._checks:
            return "no class (the recipe has none)"
        area = b.det.features["area_mm2"]

        def far(item: tuple[VisionClass, list[tuple[str, float, float]]]) -> float:
            lo, hi = item[0].ranges.get("area_mm2", (area, area))
            return max(lo - area, area - hi, 0.0) / max(hi, 1e-9)

        cls, checks = min(self._checks, key=far)
        for name, lo, hi in checks:
            v = self._feature(b, name)
            if not lo <= v <= hi:
                return (f"no class; nearest {cls.part}/{cls.pose}: {name} {v:.4g} not in "
                        f"[{lo:.4g}, {hi:.4g}]")
        return f"no class; nearest {cls.part}/{cls.pose}: its face"

    def _symmetric_angle(self, b: Blob, mode: str) -> float:
        """Angle of a class without a face to tell (orientation ``mode``): its long axis
        if it has one, else 0."""
        if mode == "none":
            return 0.0
        if mode == "principal_axis":
            if self.recipe.orientation == "principal_axis":
                return b.det.angle_deg        # measured with the blob
            return principal_angle(cv2.moments(contour_mm(b, self.calibration)))
        if self._feature(b, "aspect") > _ELONGATED:
            return principal_angle(cv2.moments(contour_mm(b, self.calibration)))
        return 0.0

    # the benchmark's pipelines orient their own outlines with it (benchmarks/vision_bench.py)
    _cut_corner = staticmethod(_cut_corner)

    # -------------------------------------------------------------- drawing

    def annotate(self, image: np.ndarray, result: LocateResult) -> np.ndarray:
        """A BGR copy of ``image`` with the result drawn as the dashboard draws it."""
        return draw(image, result, self.calibration)[0]

