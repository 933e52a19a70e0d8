"""The places where the YAML is deliberately not a mirror of the model: a part's shape
(``{disc: {...}}``, polygons recentred on their area centroid), a vision class (its
feature ranges are keys of its own), the scenario's hopper and the cell's conveyors.
Importing this module registers their builders with the walker.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from yaml.nodes import Node

from feeder_bt.config.faults import FaultPlanSpec, build_rates
from feeder_bt.config.tables import CONVEYOR_NAMES, SHAPE_KINDS, SHAPE_OPTIONAL, _num
from feeder_bt.config.walker import (
    _FIELD_BUILDERS,
    _SPECIAL_TYPES,
    _Ctx,
    _hints,
    _join,
    _required,
)
from feeder_bt.core.model import CellSpec, ConveyorSpec, PartSpec, Scenario, Shape, VisionClass
from feeder_bt.vision.features import FEATURES


def part_size_mm(part: PartSpec) -> float:
    """The largest extent of a part in any orientation and pose (its circumscribed diameter).

    Used to keep every part wholly inside some frame when frames are ``frame_spacing_mm``
    apart.
    """
    shapes = [part.shape] + [p.silhouette for p in part.poses.values() if p.silhouette]
    return max(_shape_size(s) for s in shapes)


def _shape_size(s: Shape) -> float:
    if s.kind == "disc":
        return s.diameter_mm
    if s.kind == "rect":
        return math.hypot(*s.size_mm)
    pts = s.points_mm                     # holes lie inside: the outer ring bounds the size
    return max((math.dist(a, b) for a in pts for b in pts), default=0.0)


# ============================================================================ special cases


def _build_shape(ctx: _Ctx, node: Node, path: str) -> Shape:
    """``{disc: {diameter_mm}}``, ``{rect: {size_mm: [w, h]}}`` or ``{polygon: {points_mm}}``."""
    entries = ctx.entries(node, path)
    for key, _, _ in entries:
        if key not in SHAPE_KINDS:
            ctx.unknown(key, path, SHAPE_KINDS, what="shape kind")
    if len(entries) != 1:
        got = ", ".join(k for k, _, _ in entries) or "none"
        raise ctx.error(path, f"expected exactly one shape kind of "
                              f"{', '.join(SHAPE_KINDS)}, got {got}")
    kind, _, inner = entries[0]
    kpath = _join(path, kind)
    hints = _hints(Shape)
    values: dict[str, Any] = {}
    known = SHAPE_KINDS[kind] + SHAPE_OPTIONAL.get(kind, ())
    entries = ctx.entries(inner, kpath)
    g, given = ctx.gather(inner), set()
    for key, _, vnode in entries:
        given.add(key)
        with g.step(breaks=key in known):
            if key not in known:
                ctx.unknown(key, kpath, known)
            values[key] = ctx.build(hints[key], vnode, _join(kpath, key))
    for key in SHAPE_KINDS[kind]:
        if key not in given:
            g.fail(ctx.missing(kpath, key, inner))
    g.done()
    _check_extent(ctx, kpath, values)
    if kind == "disc" and values["diameter_mm"] <= 0:
        raise ctx.error(_join(kpath, "diameter_mm"),
                        f"must be > 0, got {_num(values['diameter_mm'])}")
    if kind == "rect":
        for i, v in enumerate(values["size_mm"]):
            if v <= 0:
                raise ctx.error(f"{kpath}.size_mm[{i}]", f"must be > 0, got {_num(v)}")
    if kind == "disc" and "hole_mm" in values and not \
            0 <= values["hole_mm"] < values["diameter_mm"]:
        raise ctx.error(_join(kpath, "hole_mm"),
                        f"must be >= 0 and < diameter_mm ({_num(values['diameter_mm'])}), "
                        f"got {_num(values['hole_mm'])}")
    if kind == "polygon":
        values["points_mm"], values["holes_mm"] = _recentre(
            ctx, values["points_mm"], values.get("holes_mm", []), kpath)
    return Shape(kind=kind, **values)


#: no part outline reaches this far from its origin: a figure beyond it is a unit mistake
#: (or garbage), refused here before the geometry's products overflow to inf and nan
MAX_EXTENT_MM = 10_000.0


def _check_extent(ctx: _Ctx, kpath: str, values: dict[str, Any]) -> None:
    """Every length and coordinate of a shape within ``MAX_EXTENT_MM``."""
    figures: list[tuple[str, float]] = []
    for key in ("diameter_mm", "hole_mm"):
        if key in values:
            figures.append((_join(kpath, key), values[key]))
    for i, v in enumerate(values.get("size_mm") or []):
        figures.append((f"{kpath}.size_mm[{i}]", v))
    for i, (x, y) in enumerate(values.get("points_mm") or []):
        figures += [(f"{kpath}.points_mm[{i}]", x), (f"{kpath}.points_mm[{i}]", y)]
    for h, hole in enumerate(values.get("holes_mm") or []):
        for i, (x, y) in enumerate(hole):
            figures += [(f"{kpath}.holes_mm[{h}][{i}]", x), (f"{kpath}.holes_mm[{h}][{i}]", y)]
    for where, v in figures:
        if not abs(v) <= MAX_EXTENT_MM:
            raise ctx.error(where, f"{_num(v)} mm is beyond any part ({_num(MAX_EXTENT_MM)} mm "
                                   f"at most): a unit mistake?")


def _ring_area(pts: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Signed area and the area-weighted centroid sums (cx·6a, cy·6a) of a closed ring."""
    a = cx = cy = 0.0
    for (x0, y0), (x1, y1) in zip(pts, pts[1:] + pts[:1], strict=True):
        cross = x0 * y1 - x1 * y0
        a += cross
        cx += (x0 + x1) * cross
        cy += (y0 + y1) * cross
    return a / 2.0, cx, cy


def _inside(p: tuple[float, float], ring: list[tuple[float, float]]) -> bool:
    """Whether a point is strictly inside a closed ring (even-odd ray cast)."""
    x, y = p
    n, inside = len(ring), False
    for i in range(n):
        (x0, y0), (x1, y1) = ring[i], ring[(i + 1) % n]
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


def _recentre(ctx: _Ctx, pts: list[tuple[float, float]], holes: list[list[tuple[float, float]]],
              path: str) -> tuple[list[tuple[float, float]], list[list[tuple[float, float]]]]:
    """Move a polygon (and its holes) so the area centroid of the region is the origin (the
    part frame of ``Shape``); the polygon need not be convex."""
    ppath = _join(path, "points_mm")
    if len(pts) < 3:
        raise ctx.error(ppath, f"a polygon needs at least 3 points, got {len(pts)}")
    a, cx, cy = _ring_area(pts)
    if not math.isfinite(a) or abs(a) < 1e-9:
        raise ctx.error(ppath, "polygon has no area (points collinear or repeated)")
    sign = 1.0 if a > 0 else -1.0                 # either winding
    area, sx, sy = abs(a), sign * cx, sign * cy
    for i, hole in enumerate(holes):
        hpath = f"{path}.holes_mm[{i}]"
        if len(hole) < 3:
            raise ctx.error(hpath, f"a hole needs at least 3 points, got {len(hole)}")
        ha, hx, hy = _ring_area(hole)
        if abs(ha) < 1e-9:
            raise ctx.error(hpath, "hole has no area (points collinear or repeated)")
        for p in hole:
            if not _inside(p, pts):
                raise ctx.error(hpath, f"point [{_num(p[0])}, {_num(p[1])}] is not inside "
                                       f"the polygon's points_mm")
        hsign = 1.0 if ha > 0 else -1.0
        area -= abs(ha)
        sx -= hsign * hx
        sy -= hsign * hy
    if area <= 1e-9:
        raise ctx.error(_join(path, "holes_mm"), "the holes leave the polygon no area")
    cx, cy = sx / (6.0 * area), sy / (6.0 * area)
    return ([(x - cx, y - cy) for x, y in pts],
            [[(x - cx, y - cy) for x, y in hole] for hole in holes])


def _build_vision_class(ctx: _Ctx, node: Node, path: str) -> VisionClass:
    """``{part, pose, pickable, mirrored?, rulers?, orientation?, <feature>: [lo, hi], ...}``."""
    hints = _hints(VisionClass)
    plain = {f.name: f for f in dataclasses.fields(VisionClass) if f.name != "ranges"}
    kwargs: dict[str, Any] = {}
    ranges: dict[str, tuple[float, float]] = {}
    given, stray = set(), None
    entries = ctx.entries(node, path)
    g = ctx.gather(node)
    for key, _, vnode in entries:
        sub = _join(path, key)
        given.add(key)
        if key not in plain and key not in FEATURES:   # listed; the class may still be whole
            stray = ctx.note(ctx.unknown_error(key, path, list(plain) + list(FEATURES),
                                               what="class key or feature"))
            continue
        with g.step():
            if key in plain:
                kwargs[key] = ctx.build(hints[key], vnode, sub)
                ctx.check_field(VisionClass, key, kwargs[key], sub)
            else:
                lo, hi = ctx.build(tuple[float, float], vnode, sub)
                if lo > hi:
                    raise ctx.error(sub, f"range [lo, hi] has lo > hi: [{_num(lo)}, {_num(hi)}]")
                ranges[key] = (lo, hi)
    for fname, f in plain.items():
        if fname not in given and _required(f):
            g.fail(ctx.missing(path, fname, node))
    if not given & {*FEATURES, "rulers"}:     # a misspelt feature is that mistake already
        g.fail(stray or ctx.error(path, f"a class needs at least one feature range "
                                        f"({', '.join(FEATURES)}) or rulers"))
    g.done()
    return VisionClass(ranges=ranges, **kwargs)


def _build_hopper(ctx: _Ctx, node: Node, path: str) -> dict[str, Any]:
    """Scenario ``hopper: {parts: {name: count}}`` -> ``Scenario.hopper``."""
    parts_node = None
    for key, _, vnode in ctx.entries(node, path):
        if key != "parts":
            ctx.unknown(key, path, ["parts"])
        parts_node = vnode
    if parts_node is None:
        raise ctx.missing(path, "parts", node)
    ppath = _join(path, "parts")
    counts = ctx.build(dict[str, int], parts_node, ppath)
    g = ctx.gather()
    for name, n in counts.items():
        if n < 0:
            g.fail(ctx.error(_join(ppath, name), f"count must be >= 0, got {n}"))
    g.done()
    if not any(n > 0 for n in counts.values()):
        raise ctx.error(ppath, "the hopper needs at least one part with a count > 0")
    return {"hopper": counts}


def _build_conveyors(ctx: _Ctx, node: Node, path: str) -> dict[str, Any]:
    """Cell ``conveyors``: ``horizontal`` and ``incline`` belts, ``return: {transit_s}``."""
    conveyors = CellSpec(name="", path=Path()).conveyors   # the model's defaults
    out: dict[str, Any] = {}
    entries = ctx.entries(node, path)
    g = ctx.gather(node)
    for key, _, vnode in entries:
        sub = _join(path, key)
        with g.step(breaks=key in (*CONVEYOR_NAMES, "return")):
            if key == "return":
                for rkey, _, rnode in ctx.entries(vnode, sub):
                    if rkey != "transit_s":
                        ctx.unknown(rkey, sub, ["transit_s"])
                    v = ctx.number(rnode, _join(sub, rkey))
                    ctx.check_field(CellSpec, "return_transit_s", v, _join(sub, rkey))
                    out["return_transit_s"] = v
            elif key in CONVEYOR_NAMES:
                conveyors[key] = ctx.dataclass(ConveyorSpec, vnode, sub)
            else:
                ctx.unknown(key, path, (*CONVEYOR_NAMES, "return"), what="conveyor")
    g.done()
    out["conveyors"] = conveyors
    return out


_SPECIAL_TYPES.update({
    Shape: _build_shape,
    VisionClass: _build_vision_class,
})
_FIELD_BUILDERS.update({
    (Scenario, "hopper"): _build_hopper,
    (CellSpec, "conveyors"): _build_conveyors,
    (FaultPlanSpec, "rates"): build_rates,
})
