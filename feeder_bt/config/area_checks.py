"""A vision class against its part's outline ("no silent zero"): its area range
and its rulers' ranges.

A class whose ``area_mm2`` range cannot hold the area of the outline it names (a unit
mistake: ``diameter_mm: 2`` for a 2-inch lens) would reject every blob of that part as
"too small" or "no class" and the run would feed nothing, silently. ``feeder check``
names it instead, with both areas.

What a blob of the part can measure: the outline's area, give or take a pixel all along
its edge (threshold and blur move the edge by up to about a pixel: perimeter times
``mm_per_px``) and a few per cent of scale (the lens, the tilt, the calibration's error).
"""

from __future__ import annotations

import math

import numpy as np

from feeder_bt.config.tables import _num
from feeder_bt.config.walker import _Ctx
from feeder_bt.core.model import CellSpec, Scenario

SCALE_SLACK = 0.05             # the calibration's scale error, lens and tilt, as a fraction
LINE_STEPS_DEG = 1.0           # a line ruler is tried at every turn of the axis this apart


def _perimeter(outline: np.ndarray) -> float:
    from feeder_bt.core.geometry import rings  # geometry imports the model: not at the top
    return sum(float(np.linalg.norm(np.diff(np.vstack([r, r[:1]]), axis=0), axis=1).sum())
               for r in rings(outline))


def outline_area_span(sc: Scenario, part: str, pose: str, mm_per_px: float
                      ) -> tuple[float, float, float]:
    """The outline's area (mm²) as ``area_mm2`` measures it (inside its outer edge, holes
    included: a washer's is its disc's) and the lowest and highest area a blob of it can
    measure through a camera of ``mm_per_px``."""
    from feeder_bt.core.geometry import outer, polygon_area, pose_outline
    out = outer(pose_outline(sc.parts[part], pose))
    area = polygon_area(out)
    edge = _perimeter(out) * mm_per_px
    return area, max(area * (1 - SCALE_SLACK) - edge, 0.0), area * (1 + SCALE_SLACK) + edge


def outline_edge_mm2(sc: Scenario, part: str, pose: str, mm_per_px: float) -> float:
    """The area a pixel's width all along the outline's outer edge covers, mm²: how far
    a blob's measured area may be off the outline's (threshold, blur, pixel grid)."""
    from feeder_bt.core.geometry import outer, pose_outline
    return _perimeter(outer(pose_outline(sc.parts[part], pose))) * mm_per_px


def check_class_areas(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """Each class's ``area_mm2`` range against its outline's area, and the recipe's
    ``min_area_mm2`` against every pickable outline (see the module docstring)."""
    s = cell.camera.calibration.mm_per_px
    for i, vc in enumerate(sc.vision.classes):
        if vc.part not in sc.parts or vc.pose not in sc.parts[vc.part].poses:
            continue                              # listed by _check_scenario
        area, lo, hi = outline_area_span(sc, vc.part, vc.pose, s)
        edge = outline_edge_mm2(sc, vc.part, vc.pose, s)
        rng = vc.ranges.get("area_mm2")
        if rng is not None and (rng[1] < lo or rng[0] > hi):
            ctx.add_problem(f"vision.classes[{i}].area_mm2",
                            f"[{_num(rng[0])}, {_num(rng[1])}] cannot hold {vc.part}/{vc.pose}: "
                            f"its outline is {area:.4g} mm², measured {lo:.4g}-{hi:.4g} mm² "
                            f"at the cell's {_num(s)} mm/px; is a size in the wrong unit?")
        if vc.pickable and hi < sc.vision.min_area_mm2:
            ctx.add_problem("vision.min_area_mm2",
                            f"{_num(sc.vision.min_area_mm2)} mm² is above {vc.part}/{vc.pose}'s "
                            f"outline area {area:.4g} mm² (at most {hi:.4g} mm² measured at "
                            f"{_num(s)} mm/px): every one would be rejected as too small")
        elif vc.pickable and area - 0.5 * edge < sc.vision.min_area_mm2:
            ctx.add_problem("vision.min_area_mm2",
                            f"{_num(sc.vision.min_area_mm2)} mm² is above what {vc.part}/"
                            f"{vc.pose} measures at its low end ({area:.4g} mm² outline, "
                            f"{area - 0.5 * edge:.4g} mm² with half a pixel off its edge at "
                            f"{_num(s)} mm/px): many of them would be rejected as too small")
        if area / (s * s) < 4 * math.pi:          # under a 4-px-wide disc: no shape to see
            ctx.add_problem(f"parts.{vc.part}.shape",
                            f"{vc.part}/{vc.pose} is {area:.4g} mm², {area / (s * s):.3g} px "
                            f"at the cell's {_num(s)} mm/px: too small to see")


def check_class_rulers(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """Each class's ruler ranges against what the ruler reads on the outline it names: a
    circle's arcs exactly (a circle that misses the teeth reads 1 or 0); a line's width at
    any turn of the long axis (an outline without a clear axis may be read at any), give
    or take the scale slack and two pixels. A range that cannot hold it would reject every
    blob of the part; the usual cause is a radius or angle for another part, or in inches."""
    from feeder_bt.core.geometry import pose_outline, rings
    from feeder_bt.vision.rulers import circle_arcs, line_mm
    s = cell.camera.calibration.mm_per_px
    for i, vc in enumerate(sc.vision.classes):
        if vc.part not in sc.parts or vc.pose not in sc.parts[vc.part].poses:
            continue                              # listed by _check_scenario
        if not vc.rulers:
            continue
        outer = rings(pose_outline(sc.parts[vc.part], vc.pose))[0]
        for name, (lo, hi) in vc.rulers.items():
            ruler = sc.vision.rulers.get(name)
            if ruler is None or lo > hi:
                continue                          # listed by _check_rulers
            path = f"vision.classes[{i}].rulers.{name}"
            where = f"{vc.part}/{vc.pose}"
            if ruler.circle_mm is not None:
                n = circle_arcs(outer, (0.0, 0.0), ruler.circle_mm)
                if not lo <= n <= hi:
                    ctx.add_problem(path, f"[{_num(lo)}, {_num(hi)}] cannot hold {where}: "
                                          f"its outline has {n:g} arc(s) on the circle of "
                                          f"{_num(ruler.circle_mm)} mm; is the range or "
                                          f"the radius another part's, or the radius in "
                                          f"the wrong unit?")
            elif ruler.line_deg is not None:
                got = [line_mm(outer, (0.0, 0.0), a) for a in
                       np.arange(0.0, 180.0, LINE_STEPS_DEG)]
                least = min(got) * (1 - SCALE_SLACK) - 2 * s
                most = max(got) * (1 + SCALE_SLACK) + 2 * s
                if hi < least or lo > most:
                    ctx.add_problem(path, f"[{_num(lo)}, {_num(hi)}] cannot hold {where}: "
                                          f"across its outline the line reads "
                                          f"{min(got):.4g}-{max(got):.4g} mm; is a size in "
                                          f"the wrong unit?")
