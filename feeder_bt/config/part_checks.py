"""A part against its recipe and gripper, before the run ("no silent zero"): what would
otherwise show only as a run that feeds nothing, or faults after its misses.

* a pick point (the area centroid, or each of ``pick.grips``) in a hole or off the part:
  every pick at it misses (a ring's centroid is in its hole);
* a class range that cannot hold the outline it names, on any feature: the outline is
  drawn at the cell's scale and measured by the locator itself (``outline_features``);
* two classes whose ranges overlap on every feature both range over: a blob in both is
  taken as the first, whichever part it is;
* an outline that ``orientation: outline`` cannot match on itself, drawn at the cell's
  scale (ambiguous, or under ``outline_match.min_iou``): every blob of it rejected;
* a part placed oriented by a class that cannot orient it: ``principal_axis`` when its
  symmetry is not 2 (a long axis gives an angle modulo 180°), ``moment`` when its ends
  weigh the same, ``none`` at all;
* a belt speed that looks like m/s (under ``MIN_BELT_MM_S``).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import numpy as np

from feeder_bt.config.tables import _num
from feeder_bt.config.walker import _Ctx
from feeder_bt.core.model import CellSpec, PartSpec, Scenario, VisionClass
from feeder_bt.vision.features import PIXEL_FEATURES

if TYPE_CHECKING:
    from feeder_bt.core.model import VisionRecipe
    from feeder_bt.vision.pixels import Calibration

#: Below this a belt speed is a unit mistake: at 1 mm/s a part takes 20 minutes to cross a
#: 1.2 m belt, which no feeder does, while every belt speed written in m/s is below it
#: (a cell's conveyors top out at a few tenths of a m/s).
MIN_BELT_MM_S = 1.0

#: How much of a feature a blob of the part may measure off the drawn outline's: the
#: calibration's scale (lens, tilt: ``area_checks.SCALE_SLACK``) for sizes, and for the
#: ratios of shape what threshold, blur and noise move on a blob (a few per cent; more
#: on a small blob: ``PIXEL_SLACK`` over its size in pixels).
SIZE_SLACK = 0.05
RATIO_SLACK = 0.05
HU_SLACK = 0.10
PIXEL_SLACK = 1.5
#: The drawn outline is measured at these turns (the pixel grid changes what a blob
#: measures: a rectangle square to it is exactly rectangular, one at 30° is not).
DRAW_TURNS_DEG = (0.0, 15.0, 30.0, 45.0, 60.0, 75.0)
_MARGIN_PX = 8
SUPERSAMPLE = 4               # sub-pixels per pixel, each axis, as ``sim.render`` draws


# ---------------------------------------------------------------------------- grips


def _material_depth(outline: np.ndarray, x: float, y: float) -> float:
    """Signed distance from ``(x, y)`` to the outline's edge: > 0 on the part's material,
    < 0 in a hole or off the part."""
    import cv2

    from feeder_bt.core.geometry import rings
    rs = rings(outline)
    depths = []
    for k, r in enumerate(rs):
        d = cv2.pointPolygonTest(np.asarray(r, np.float32).reshape(-1, 1, 2),
                                 (float(x), float(y)), True)
        depths.append(d if k == 0 else -d)      # inside a hole is off the material
    return min(depths)


def _suggest_grip(outline: np.ndarray, need_mm: float) -> tuple[float, float] | None:
    """A point of material near the centroid with ``need_mm`` of it all round (the cup's
    radius) and as much more as it gains for the way from the centroid (mid-material on a
    ring), on a 0.5 mm grid; None if there is none."""
    from feeder_bt.core.geometry import outer
    o = outer(outline)
    lo, hi = o.min(axis=0), o.max(axis=0)
    best, score = None, -math.inf
    for x in np.arange(math.floor(lo[0] * 2) / 2, hi[0] + 0.5, 0.5):
        for y in np.arange(math.floor(lo[1] * 2) / 2, hi[1] + 0.5, 0.5):
            d = _material_depth(outline, float(x), float(y))
            if d < need_mm + 0.25:
                continue
            sc = d - 0.5 * math.hypot(x, y) + 1e-6 * (x - abs(y))   # ties: along +x
            if sc > score:
                best, score = (float(x), float(y)), sc
    return best


def check_grips(sc: Scenario, ctx: _Ctx) -> None:
    """Each pickable pose's pick points on the part's material, the cup whole on it."""
    from feeder_bt.core.geometry import pose_outline
    for name, part in sc.parts.items():
        pick = part.pick
        grips = [(g.offset_mm, f"parts.{name}.pick.grips[{i}].offset_mm")
                 for i, g in enumerate(pick.grips)] if pick is not None else []
        if not grips:
            grips = [((0.0, 0.0), f"parts.{name}.pick" if pick is not None
                      else f"parts.{name}.shape")]
        cup = pick.cup_radius_mm if pick is not None else 0.0
        outlines = {pname: pose_outline(part, pname) for pname, pose in part.poses.items()
                    if pose.pickable}
        for (gx, gy), path in grips:
            for pname, outline in outlines.items():
                ox, oy = gx, (-gy if part.poses[pname].mirror else gy)   # mirrored with it
                depth = _material_depth(outline, ox, oy)
                what = "(the area centroid)" if pick is None else f"({_num(ox)}, {_num(oy)})"
                if depth < 0:
                    where = "in a hole" if _in_hole(outline, ox, oy) else "off the part"
                elif cup > 0 and depth < cup:
                    where = (f"{depth:.3g} mm from the part's edge: the cup "
                             f"({_num(cup)} mm radius) overhangs it and cannot seal")
                else:
                    continue
                fix = _suggest_grip(outline, cup)
                hint = (f"; grip on the material, e.g. pick: {{grips: [{{offset_mm: "
                        f"[{_num(fix[0])}, {_num(fix[1])}]}}]}}" if fix is not None
                        else "; no point of this outline holds the cup")
                ctx.add_problem(path, f"the pick point {what} of {name}/{pname} lies "
                                      f"{where}: every pick there misses{hint}",
                                line=ctx.key_lines.get(path))
                break                                # one line a grip, its first pose


def _in_hole(outline: np.ndarray, x: float, y: float) -> bool:
    import cv2

    from feeder_bt.core.geometry import rings
    return any(cv2.pointPolygonTest(np.asarray(r, np.float32).reshape(-1, 1, 2),
                                    (float(x), float(y)), False) >= 0
               for r in rings(outline)[1:])


# ---------------------------------------------------------------------------- features


def _drawn(part: PartSpec, pose: str, mm_per_px: float, turns: tuple[float, ...]
           ) -> Iterator[tuple[float, np.ndarray]]:
    """The pose's outline drawn light on dark at ``mm_per_px`` (origin at the middle of a
    square frame, a calibration of that scale without turn: ``_drawing_calibration``) at
    each turn, as the simulated camera draws it (sub-pixels, area-averaged, so that a
    pixel is the part's when over half of it is: a blurred edge thresholded midway)."""
    import cv2

    from feeder_bt.core.geometry import circumradius, place_outline, pose_outline, rings
    cal = _drawing_calibration(mm_per_px)
    outline = pose_outline(part, pose)
    r_px = circumradius(outline) / mm_per_px
    side = int(math.ceil(2 * r_px)) + 2 * _MARGIN_PX
    side = -(-side // 64) * 64                              # whole words of pixels
    centre = side / 2.0
    k = SUPERSAMPLE
    for turn in turns:
        placed = place_outline(outline, 0.0, 0.0, turn)
        fine = np.zeros((side * k, side * k), np.uint8)
        px = [np.round(((cal.mm_to_px(r) + centre) * k + (k - 1) / 2.0) * 16)
              .astype(np.int32).reshape(-1, 1, 2) for r in rings(placed)]
        cv2.fillPoly(fine, px, 255, lineType=cv2.LINE_8, shift=4)   # holes left dark
        yield turn, cv2.resize(fine, (side, side), interpolation=cv2.INTER_AREA)


def _drawing_calibration(mm_per_px: float) -> Calibration:
    from feeder_bt.core.model import CameraCalibration
    from feeder_bt.vision.pixels import Calibration
    return Calibration(CameraCalibration(origin_mm=(0.0, 0.0), mm_per_px=mm_per_px))


def _drawing_recipe(recipe: VisionRecipe, **kw: Any) -> VisionRecipe:
    """A recipe that finds a drawn outline (light on dark, no golden image), with the
    scenario's ``min_hole_mm2`` and ``outline_match``."""
    from feeder_bt.core.model import Morphology, Threshold, VisionRecipe
    return VisionRecipe(backlight=False, golden_image=False, foreground="light",
                        threshold=Threshold(method="fixed", value=127),
                        morphology=Morphology(), min_area_mm2=0.0,
                        min_hole_mm2=recipe.min_hole_mm2,
                        outline_match=recipe.outline_match, **kw)


def outline_features(part: PartSpec, pose: str, recipe: VisionRecipe, mm_per_px: float
                     ) -> dict[str, tuple[float, float]]:
    """Each feature's lowest and highest value on the pose's outline drawn at
    ``mm_per_px`` at several turns (``DRAW_TURNS_DEG``), measured by the locator's own
    code (``Locator.measure_blobs``) on the drawn frame: no second feature extractor to
    disagree with the one that feeds. Not the features read from the pixels
    (``PIXEL_FEATURES``): the drawing's grey is not the part's."""
    from feeder_bt.vision.locator import Locator

    locator = Locator(_drawing_recipe(recipe, classes=[]), {part.name: part},
                      _drawing_calibration(mm_per_px))
    spans: dict[str, tuple[float, float]] = {}
    for _, img in _drawn(part, pose, mm_per_px, DRAW_TURNS_DEG):
        dets = [d for d in locator.measure_blobs(img) if not d.reason]
        if not dets:
            continue
        feats = max(dets, key=lambda d: d.features["area_mm2"]).features
        for name, v in feats.items():
            if name in PIXEL_FEATURES:
                continue
            lo, hi = spans.get(name, (v, v))
            spans[name] = (min(lo, v), max(hi, v))
    return spans


def feature_slack(name: str, value: float, area_mm2: float, mm_per_px: float) -> float:
    """How far a blob of the part may measure ``name`` off the drawn outline's ``value``
    (see ``SIZE_SLACK``...): sizes by the scale's error and a pixel's width, ratios by
    a few per cent and more on a small blob, the hole count not at all."""
    size_px = max(math.sqrt(max(area_mm2, 0.0)) / mm_per_px, 1.0)
    v = abs(value)
    if name == "holes":
        return 0.0
    if name in ("area_mm2", "hole_area_mm2"):
        edge = math.sqrt(math.pi * v) * mm_per_px     # half a pixel round a disc of it
        return SIZE_SLACK * v + edge
    if name == "perimeter_mm":
        return SIZE_SLACK * v + 2.0 * mm_per_px
    if name in ("hu1", "hu2"):
        return v * (HU_SLACK + 2 * PIXEL_SLACK / size_px)
    return v * (RATIO_SLACK + PIXEL_SLACK / size_px)


def _class_spans(sc: Scenario, cell: CellSpec) -> dict[int, dict[str, tuple[float, float]]]:
    """Each (known part, pose) class's drawn-outline spans widened by ``feature_slack``."""
    s = cell.camera.calibration.mm_per_px
    out: dict[int, dict[str, tuple[float, float]]] = {}
    memo: dict[tuple[str, str], dict[str, tuple[float, float]]] = {}
    for i, vc in enumerate(sc.vision.classes):
        if vc.part not in sc.parts or vc.pose not in sc.parts[vc.part].poses:
            continue
        key = (vc.part, vc.pose)
        if key not in memo:
            raw = outline_features(sc.parts[vc.part], vc.pose, sc.vision, s)
            area = raw.get("area_mm2", (0.0, 0.0))[0]
            memo[key] = {k: (lo - feature_slack(k, lo, area, s), hi + feature_slack(k, hi, area, s))
                         for k, (lo, hi) in raw.items()}
            memo[key]["_raw"] = raw      # type: ignore[assignment]
        out[i] = memo[key]
    return out


def check_class_features(sc: Scenario, ctx: _Ctx, cell: CellSpec,
                         spans: dict[int, dict[str, tuple[float, float]]]) -> None:
    """Each class's ranges (but ``area_mm2``, ``area_checks``' own) against what a blob of
    its outline measures: a range that cannot hold it rejects every such blob."""
    s = cell.camera.calibration.mm_per_px
    for i, vc in enumerate(sc.vision.classes):
        span = spans.get(i)
        if span is None:
            continue
        raw = span["_raw"]                    # type: ignore[index]
        for name, (lo, hi) in vc.ranges.items():
            if name == "area_mm2" or name not in span:
                continue
            mlo, mhi = span[name]
            if hi < mlo or lo > mhi:
                rlo, rhi = raw[name]
                drawn = f"{rlo:.4g}" if math.isclose(rlo, rhi, rel_tol=1e-3) \
                    else f"{rlo:.4g}-{rhi:.4g}"
                ctx.add_problem(f"vision.classes[{i}].{name}",
                                f"[{_num(lo)}, {_num(hi)}] cannot hold {vc.part}/{vc.pose}: "
                                f"its outline drawn at the cell's {_num(s)} mm/px measures "
                                f"{drawn}, a blob of it {mlo:.4g}-{mhi:.4g}: every one "
                                f"would fit no class")


def _overlap(a: VisionClass, b: VisionClass) -> list[str] | None:
    """The features (and rulers) both classes range over, if every one's ranges overlap;
    None if one of them separates the classes (or their faces do)."""
    if a.mirrored is not None and b.mirrored is not None and a.mirrored != b.mirrored:
        return None
    shared: list[str] = []
    for mine, theirs in ((a.ranges, b.ranges), (a.rulers, b.rulers)):
        for name in mine.keys() & theirs.keys():
            (alo, ahi), (blo, bhi) = mine[name], theirs[name]
            if ahi < blo or bhi < alo:
                return None
            shared.append(name)
    return sorted(shared)


def check_class_overlap(sc: Scenario, ctx: _Ctx,
                        spans: dict[int, dict[str, tuple[float, float]]]) -> None:
    """Two classes that a blob can fit both: the locator takes the first, so a blob of the
    second's part is named the first's. Names both and a feature whose measured spans on
    the two outlines do not meet (a range on it would tell them apart), or that none does."""
    classes = sc.vision.classes
    named = {e.key.split("]", 1)[0] + "]" for e in ctx.problems
             if (e.key or "").startswith("vision.classes[")}     # a range already wrong
    for j, b in enumerate(classes):
        for i in range(j):
            a = classes[i]
            if f"vision.classes[{i}]" in named or f"vision.classes[{j}]" in named:
                continue                          # that mistake first, not its echo
            shared = _overlap(a, b)
            if shared is None:
                continue
            both = f"{a.part}/{a.pose} (vision.classes[{i}])"
            on = (f"on every feature both range over ({', '.join(shared)})" if shared
                  else "(they range over no feature in common)")
            sa, sb = spans.get(i), spans.get(j)
            tell = _separating(sa, sb, a, b) if sa is not None and sb is not None else ""
            ctx.add_problem(f"vision.classes[{j}]",
                            f"{b.part}/{b.pose} overlaps {both} {on}: a blob in both is "
                            f"taken as {a.part}/{a.pose}; {tell}",
                            line=ctx.key_lines.get(f"vision.classes[{j}]"))


def _separating(sa: dict, sb: dict, a: VisionClass, b: VisionClass) -> str:
    """Words naming the feature that best tells the two outlines apart, or that none does."""
    ra, rb = sa["_raw"], sb["_raw"]
    best, gap = None, 0.0
    for name in ra.keys() & rb.keys():
        if name.startswith("_") or name in ("mirrored", "split"):
            continue
        (alo, ahi), (blo, bhi) = sa[name], sb[name]
        if ahi < blo or bhi < alo:
            g = max(blo - ahi, alo - bhi) / max(abs(ahi), abs(bhi), 1e-9)
            if name == "holes":
                g += 1.0                               # a count: the surest of all
            if g > gap:
                best, gap = name, g
    if best is None:
        return ("no feature tells their outlines apart: drop one class, or give them "
                "faces (mirrored) or rulers that differ")
    va, vb = ra[best], rb[best]
    fa = f"{va[0]:.4g}" if math.isclose(*va, rel_tol=1e-3) else f"{va[0]:.4g}-{va[1]:.4g}"
    fb = f"{vb[0]:.4g}" if math.isclose(*vb, rel_tol=1e-3) else f"{vb[0]:.4g}-{vb[1]:.4g}"
    return (f"{best} tells them apart ({a.part}/{a.pose} measures {fa}, {b.part}/{b.pose} "
            f"{fb}): give both a range of it")


def check_classes_against_outlines(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """``check_class_features`` and ``check_class_overlap`` on one set of drawn outlines."""
    if not sc.vision.classes:
        return
    spans = _class_spans(sc, cell)
    check_class_features(sc, ctx, cell, spans)
    check_class_overlap(sc, ctx, spans)
    check_outline_orientation(sc, ctx, cell)


#: ``check_outline_orientation`` draws each outline at these turns.
ORIENT_TURNS_DEG = (10.0, 105.0, 200.0)


def check_outline_orientation(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """Each pickable class oriented by its outline, run on its own outline drawn at the
    cell's scale (``_drawn``) by the locator itself: an outline that does not match itself
    (``outline_match.min_iou`` too high for the raster) or whose poses overlap it alike
    (ambiguous: a part that looks the same turned or turned over, and is not declared so)
    would have every blob of it rejected, and the run would feed nothing."""
    from feeder_bt.vision.locator import Locator
    s = cell.camera.calibration.mm_per_px
    seen: set[tuple[str, str]] = set()
    for i, vc in enumerate(sc.vision.classes):
        part = sc.parts.get(vc.part)
        mode = vc.orientation or sc.vision.orientation
        if mode != "outline" or part is None or vc.pose not in part.poses or not vc.pickable:
            continue
        # one outline, one line: the poses showing the part's shape (either face) match it
        shows = (vc.part, vc.pose if part.poses[vc.pose].silhouette is not None else "")
        if shows in seen:
            continue
        seen.add(shows)
        one = VisionClass(part=vc.part, pose=vc.pose, pickable=True,
                          ranges={"area_mm2": (0.0, math.inf)})
        locator = Locator(_drawing_recipe(sc.vision, classes=[one], orientation="outline"),
                          {vc.part: part}, _drawing_calibration(s))
        why = []
        for _, img in _drawn(part, vc.pose, s, ORIENT_TURNS_DEG):
            why += [d.reason for d in locator.locate(img).rejected if d.reason]
        if not why:
            continue
        where = f"vision.classes[{i}].orientation" if vc.orientation else "vision.orientation"
        reason = why[0].removeprefix("no class (").removesuffix(")")
        if "ambiguous" in reason:
            fix = ("if it looks the same turned, give its symmetry; if turned over, "
                   "mirror_symmetric: true; else tell its ends apart by a feature it has "
                   "(orientation: moment for a heavier end)")
        else:
            fix = "lower outline_match.min_iou"
        ctx.add_problem(where, f"outline cannot orient {vc.part}/{vc.pose}: its own outline, "
                               f"drawn at the cell's {_num(s)} mm/px, reads \"{reason}\" at "
                               f"{len(why)} of {len(ORIENT_TURNS_DEG)} turns, so blobs of it "
                               f"would be rejected; {fix}")


# ---------------------------------------------------------------------------- orientation


def check_orientation(sc: Scenario, ctx: _Ctx) -> None:
    """Each pickable class of a part placed oriented (``place.orient``), by its own
    orientation (else the recipe's): ``principal_axis`` tells the angle modulo 180°, which
    is the part's own period only when ``symmetry`` is 2 (or when any angle is within its
    orientation tolerance, as for a disc); ``moment`` needs an end heavier than the other;
    ``none`` places every part at the angle it lay. A recipe with a ``leaf`` locator reads
    angles its own way: not checked."""
    from feeder_bt.vision.outline import MIN_SKEW, MomentModel
    if sc.vision.leaf:
        return                                        # its own locator reads the angle
    seen: set[tuple[str, str, str]] = set()
    for i, vc in enumerate(sc.vision.classes):
        part = sc.parts.get(vc.part)
        mode = vc.orientation or sc.vision.orientation
        if part is None or vc.pose not in part.poses or not vc.pickable \
                or not part.place.orient or (vc.part, vc.pose, mode) in seen:
            continue
        seen.add((vc.part, vc.pose, mode))
        where = f"vision.classes[{i}].orientation" if vc.orientation \
            else "vision.orientation"
        n, tol = part.symmetry, part.orientation_tolerance_deg
        if part.period_deg <= 2 * tol:
            continue                                  # any angle is near enough
        if mode == "principal_axis" and n != 2:
            if n == 1:
                why = ("its long axis is the same turned 180°, the part is not (symmetry: 1): "
                       "about half would be placed turned round")
            else:
                why = (f"a part with symmetry {n} has no long axis (its second moments are "
                       f"the same every way), so the angle read is noise")
            ctx.add_problem(where, f"principal_axis cannot orient {vc.part} (place.orient): "
                                   f"{why}; use cut_corner, outline or moment, or symmetry: 2 "
                                   f"if the part looks the same turned half a turn")
        elif mode == "moment" and n == 1 and not (m := MomentModel(part, vc.pose)).usable:
            why = ("it has no long axis" if m.skew >= MIN_SKEW else
                   f"its ends weigh the same (skewness {m.skew:.2f} along its long axis)")
            ctx.add_problem(where, f"moment cannot orient {vc.part}/{vc.pose} (place.orient): "
                                   f"{why}, so about half would be placed turned round; "
                                   f"use outline")
        elif mode == "none":
            ctx.add_problem(where, f"{vc.part}/{vc.pose} is placed oriented (place.orient) "
                                   f"but its class reads no angle (orientation: none): each "
                                   f"is placed turned as it lay; choose principal_axis, "
                                   f"cut_corner, outline or moment")


# ---------------------------------------------------------------------------- speeds


def check_speed_units(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """A belt speed under ``MIN_BELT_MM_S`` (the horizontal belt's, or an adjuster's
    ``*_mm_s`` given in the file) is named as a likely m/s figure."""
    hmax = cell.conveyors["horizontal"].max_mm_s
    length = cell.conveyors["horizontal"].length_mm
    given = [("present.horizontal_mm_s", sc.present.horizontal_mm_s)]
    given += [(f"adjust.params.{k}", v) for k, v in sc.adjust.params.items()
              if k.endswith("_mm_s")]
    for path, v in given:
        if not 0 < v < MIN_BELT_MM_S:
            continue
        crossing = length / v / 60.0
        as_ms = v * 1000.0
        fits = (f"within the horizontal conveyor's max_mm_s {_num(hmax)}" if as_ms <= hmax
                else f"above the horizontal conveyor's max_mm_s {_num(hmax)}")
        ctx.add_problem(path, f"{_num(v)} mm/s: is this m/s? {_num(as_ms)} mm/s is {fits}; "
                              f"at {_num(v)} mm/s a part takes {crossing:.0f} min to cross "
                              f"the {_num(length)} mm belt (under {_num(MIN_BELT_MM_S)} mm/s "
                              f"no feeder runs)")
