"""Load and validate scenario and cell YAML files into the dataclasses of ``model.py``.

The YAML is walked as *nodes* (``yaml.compose``), never as plain Python data, so that every
problem can be reported as one line ``FILE:LINE: dotted.key: what is wrong`` (a
``ConfigError``) instead of a traceback far from the cause.

The mapping from YAML to the model is generic: it follows the dataclass fields and type
hints of ``model.py``, so a new field with a default there is a new optional YAML key here.
Only the few places where the YAML is deliberately not a mirror of the model are special
(``Shape``, ``VisionClass``, ``Scenario.hopper``, ``CellSpec.conveyors``).

The tables of allowed values (enumerations, numeric ranges, adjuster parameters) are module
constants so that other modules (CLI, docs, adjusters) can reuse them.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import math
import os
import re
import types
import typing
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from feeder_bt.adjusters import ADJUSTERS, AdjusterParamError
from feeder_bt.errors import ConfigError
from feeder_bt.scenario.faults import (
    COMMS_DEVICES,
    FAULT_KINDS,
    PHASES,
    FaultPlanSpec,
    FaultRate,
    ScriptedFault,
    build_rates,
    check_fault_plan,
)
from feeder_bt.scenario.model import (
    AdeptSpec,
    AdjustParams,
    CameraCalibration,
    CameraSpec,
    CellSpec,
    ConveyorSpec,
    EncoderSpec,
    GalilSpec,
    HopperSpec,
    IoSignal,
    LocateParams,
    Morphology,
    PartSpec,
    PresentParams,
    RenderSpec,
    RetrieveParams,
    RobotSpec,
    Scenario,
    Shape,
    StablePose,
    TargetSpec,
    Threshold,
    VisionClass,
    VisionRecipe,
)
from feeder_bt.scenario.plugins import import_near
from feeder_bt.vision.features import FEATURES

__all__ = [
    "ADJUST_ALGORITHMS", "ADJUST_ORDER", "ADJUST_PARAMS", "CELL_HALS", "CONVEYOR_NAMES",
    "ENUMS", "FOREGROUNDS", "IO_DIRS", "LEAF_RE", "ORIENTATION_METHODS", "PRESENT_MODES",
    "PROBABILITY_TOLERANCE", "RANGES", "RETRIEVE_POLICIES", "SHAPE_KINDS", "THRESHOLD_METHODS",
    "Range", "check_files", "load_cell", "load_fault_plan", "load_scenario", "part_size_mm",
]

# ============================================================================ allowed values

PRESENT_MODES: tuple[str, ...] = ("continuous", "incremental")
RETRIEVE_POLICIES: tuple[str, ...] = ("fifo", "earliest_deadline", "shortest_cycle",
                                      "lookahead")
THRESHOLD_METHODS: tuple[str, ...] = ("fixed", "otsu", "adaptive")
FOREGROUNDS: tuple[str, ...] = ("dark", "light")
LIGHTINGS: tuple[str, ...] = ("backlit", "frontlit")
TARGET_KINDS: tuple[str, ...] = ("chessboard", "circles", "acircles", "charuco")
ORIENTATION_METHODS: tuple[str, ...] = ("none", "principal_axis", "cut_corner")
CELL_HALS: tuple[str, ...] = ("sim", "emulated", "real")
IO_DIRS: tuple[str, ...] = ("in", "out")

#: Shape kinds and the ``Shape`` fields each one is written with (all required).
SHAPE_KINDS: dict[str, tuple[str, ...]] = {
    "disc": ("diameter_mm",),
    "rect": ("size_mm",),
    "polygon": ("points_mm",),
}
#: Optional ``Shape`` fields of each kind (holes).
SHAPE_OPTIONAL: dict[str, tuple[str, ...]] = {"disc": ("hole_mm",), "polygon": ("holes_mm",)}

#: Conveyors a cell describes; ``return`` is not a belt, only its transit time.
CONVEYOR_NAMES: tuple[str, ...] = ("horizontal", "incline")

#: Tolerance on the sum of a part's pose probabilities.
PROBABILITY_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Range:
    """A numeric interval; ``None`` bounds are open-ended, ``*_open`` excludes the bound."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, v: float) -> bool:
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def describe(self) -> str:
        if self.lo is not None and self.hi is not None:
            return (f"in {'(' if self.lo_open else '['}{_num(self.lo)}, "
                    f"{_num(self.hi)}{')' if self.hi_open else ']'}")
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {_num(self.lo)}"
        if self.hi is not None:
            return f"{'<' if self.hi_open else '<='} {_num(self.hi)}"
        return "any number"


POSITIVE = Range(lo=0, lo_open=True)
NON_NEGATIVE = Range(lo=0)
GREY = Range(0, 255)

#: Enumerated string fields: (dataclass, field) -> allowed values.
ENUMS: dict[tuple[type, str], tuple[str, ...]] = {
    (PresentParams, "mode"): PRESENT_MODES,
    (RetrieveParams, "policy"): RETRIEVE_POLICIES,
    (Threshold, "method"): THRESHOLD_METHODS,
    (VisionRecipe, "orientation"): ORIENTATION_METHODS,
    (VisionRecipe, "foreground"): FOREGROUNDS,
    (RenderSpec, "lighting"): LIGHTINGS,
    (TargetSpec, "kind"): TARGET_KINDS,
    (CellSpec, "hal"): CELL_HALS,
    (IoSignal, "dir"): IO_DIRS,
    (GalilSpec, "servo_on"): ("start", "reconnect", "never"),
    (GalilSpec, "free_handles"): ("ours", "others", "none"),
}

#: Numeric fields: (dataclass, field) -> allowed interval. Cross-file limits (conveyor
#: max speeds, camera window) are checked separately in ``load_scenario``.
RANGES: dict[tuple[type, str], Range] = {
    (Scenario, "tick_hz"): Range(5, 1000),
    (StablePose, "probability"): Range(0, 1),
    (PartSpec, "orientation_tolerance_deg"): Range(0, 180, lo_open=True),
    (Threshold, "value"): GREY,
    (Threshold, "block_px"): Range(lo=3),
    (Morphology, "open_px"): NON_NEGATIVE,
    (Morphology, "close_px"): NON_NEGATIVE,
    (VisionRecipe, "min_area_mm2"): NON_NEGATIVE,
    (VisionRecipe, "min_hole_mm2"): NON_NEGATIVE,
    (PresentParams, "horizontal_mm_s"): POSITIVE,
    (PresentParams, "incline_pct"): Range(0, 200),
    (PresentParams, "big_advance_mm"): POSITIVE,
    (PresentParams, "small_advance_mm"): POSITIVE,
    (PresentParams, "big_advance_incline_mm"): POSITIVE,
    (LocateParams, "frame_spacing_mm"): POSITIVE,
    (LocateParams, "dedupe_mm"): NON_NEGATIVE,
    (RetrieveParams, "robot_speed_pct"): Range(0, 200, lo_open=True),
    (RetrieveParams, "too_far_mm"): POSITIVE,
    (RetrieveParams, "reach_time_s"): NON_NEGATIVE,
    (AdjustParams, "period_s"): POSITIVE,
    (ConveyorSpec, "length_mm"): POSITIVE,
    (ConveyorSpec, "width_mm"): POSITIVE,
    (ConveyorSpec, "max_mm_s"): POSITIVE,
    (ConveyorSpec, "accel_mm_s2"): POSITIVE,
    (CellSpec, "return_transit_s"): NON_NEGATIVE,
    (EncoderSpec, "counts_per_mm"): POSITIVE,
    (EncoderSpec, "conveyor_bits"): Range(8, 64),
    (EncoderSpec, "robot_bits"): Range(8, 64),
    (EncoderSpec, "robot_start"): NON_NEGATIVE,
    (HopperSpec, "release_per_mm"): NON_NEGATIVE,
    (HopperSpec, "nominal_fill"): Range(lo=1),
    (CameraSpec, "width_px"): Range(lo=1),
    (CameraSpec, "height_px"): Range(lo=1),
    (CameraSpec, "exposure_ms"): POSITIVE,
    (CameraSpec, "grab_s"): NON_NEGATIVE,
    (CameraSpec, "vision_latency_s"): NON_NEGATIVE,
    (CameraCalibration, "mm_per_px"): POSITIVE,
    (TargetSpec, "pitch_mm"): POSITIVE,
    (TargetSpec, "dot_mm"): POSITIVE,
    (TargetSpec, "marker_mm"): NON_NEGATIVE,
    (RenderSpec, "backlight"): GREY,
    (RenderSpec, "falloff"): Range(0, 1),
    (RenderSpec, "part_grey"): GREY,
    (RenderSpec, "belt_grey"): GREY,
    (RenderSpec, "shading"): Range(0, 1),
    (RenderSpec, "highlight"): Range(0, 255),
    (RenderSpec, "noise_sigma"): NON_NEGATIVE,
    (RenderSpec, "blur_px"): NON_NEGATIVE,
    (RobotSpec, "reach_mm"): POSITIVE,
    (RobotSpec, "inner_reach_mm"): NON_NEGATIVE,
    (RobotSpec, "v_max_mm_s"): POSITIVE,
    (RobotSpec, "a_max_mm_s2"): POSITIVE,
    (RobotSpec, "approach_mm"): NON_NEGATIVE,
    (RobotSpec, "grip_s"): NON_NEGATIVE,
    (RobotSpec, "release_s"): NON_NEGATIVE,
    (RobotSpec, "track_settle_s"): NON_NEGATIVE,
    (RobotSpec, "grip_tolerance_mm"): POSITIVE,
    (RobotSpec, "command_overhead_s"): NON_NEGATIVE,
    (LocateParams, "max_parts_per_look"): NON_NEGATIVE,
    (IoSignal, "bit"): NON_NEGATIVE,
    (GalilSpec, "baud"): POSITIVE,
    (GalilSpec, "timeout_s"): POSITIVE,
    (GalilSpec, "latch_input"): Range(1, 8),
    (GalilSpec, "notify_mm"): POSITIVE,
    (GalilSpec, "watchdog_s"): Range(0.2, 60),
    (GalilSpec, "stall_mm"): POSITIVE,
    (AdeptSpec, "motion_port"): Range(1, 65535),
    (AdeptSpec, "position_port"): Range(1, 65535),
    (AdeptSpec, "io_port"): Range(1, 65535),
    (AdeptSpec, "notify_port"): Range(1, 65535),
    (AdeptSpec, "timeout_s"): POSITIVE,
    (AdeptSpec, "motion_timeout_s"): POSITIVE,
    (AdeptSpec, "poll_hz"): Range(1, 200),
    # fault plans (feeder_bt.scenario.faults)
    (FaultRate, "per_pick"): Range(0, 1),
    (FaultRate, "per_frame"): Range(0, 1),
    (FaultRate, "per_hour"): NON_NEGATIVE,
    (FaultRate, "outage_s"): POSITIVE,
    (ScriptedFault, "at_s"): NON_NEGATIVE,
    (ScriptedFault, "release_after_s"): POSITIVE,
    (ScriptedFault, "outage_s"): POSITIVE,
}
ENUMS[(FaultRate, "device")] = COMMS_DEVICES
ENUMS[(ScriptedFault, "device")] = COMMS_DEVICES
ENUMS[(ScriptedFault, "kind")] = FAULT_KINDS
ENUMS[(ScriptedFault, "phase")] = PHASES
ENUMS[(AdeptSpec, "belt_direction")] = ("forward", "reverse")

#: Adjuster algorithms and the ``adjust.params`` keys each accepts (all optional; an
#: adjuster supplies its own defaults). Keys ending in ``_mm_s`` are horizontal belt speeds
#: and are also checked against the cell's conveyor limits.
ADJUST_PARAMS: dict[str, dict[str, Range]] = {
    "none": {},
    "water_marks": {
        "high": NON_NEGATIVE, "low": NON_NEGATIVE, "gain": POSITIVE, "step": POSITIVE,
        "min_mm_s": POSITIVE, "max_mm_s": POSITIVE, "median_mm_s": POSITIVE,
    },
    "queue_proportional": {
        "target": NON_NEGATIVE, "gain": POSITIVE,
        "min_mm_s": POSITIVE, "max_mm_s": POSITIVE, "nominal_mm_s": POSITIVE,
    },
    "supply_queue": {
        "target_queue": NON_NEGATIVE, "gain_pct": NON_NEGATIVE,
        "min_incline_pct": Range(0, 200), "max_incline_pct": Range(0, 200),
        "horizontal_mm_s": POSITIVE, "pull": Range(0, 1),
        "min_mm_s": POSITIVE, "max_mm_s": POSITIVE,
    },
}
ADJUST_ALGORITHMS: tuple[str, ...] = tuple(ADJUST_PARAMS)
ENUMS[(AdjustParams, "algorithm")] = ADJUST_ALGORITHMS

#: Ordering constraints between adjuster parameters: (algorithm, smaller, larger, strict).
ADJUST_ORDER: tuple[tuple[str, str, str, bool], ...] = (
    ("water_marks", "low", "high", True),
    ("water_marks", "min_mm_s", "median_mm_s", False),
    ("water_marks", "median_mm_s", "max_mm_s", False),
    ("water_marks", "min_mm_s", "max_mm_s", False),
    ("queue_proportional", "min_mm_s", "nominal_mm_s", False),
    ("queue_proportional", "nominal_mm_s", "max_mm_s", False),
    ("queue_proportional", "min_mm_s", "max_mm_s", False),
    ("supply_queue", "min_incline_pct", "max_incline_pct", False),
    ("supply_queue", "min_mm_s", "horizontal_mm_s", False),
    ("supply_queue", "horizontal_mm_s", "max_mm_s", False),
    ("supply_queue", "min_mm_s", "max_mm_s", False),
)

LEAF_RE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*$")

# Model fields that are not YAML keys of their class (filled by a special builder or the
# loader). Fields typed ``Path`` are always loader-filled.
_IMPLIED_FIELDS: dict[type, frozenset[str]] = {CellSpec: frozenset({"return_transit_s"})}
# YAML keys that are not model fields (read by the loader itself).
_EXTRA_KEYS: dict[type, frozenset[str]] = {Scenario: frozenset({"cell"})}

# ============================================================================ helpers


def _num(v: float) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def _one_line(s: str) -> str:
    return " ".join(str(s).split())


def _short(v: Any, limit: int = 40) -> str:
    r = repr(v)
    return r if len(r) <= limit else r[: limit - 3] + "..."


def _describe(v: Any) -> str:
    """How a wrong value is named in a message: its YAML kind and the value."""
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"boolean {str(v).lower()}"
    if isinstance(v, int):
        return f"integer {_short(v)}"
    if isinstance(v, float):
        return f"number {_num(v)}"
    if isinstance(v, str):
        return f"string {_short(v)}"
    if isinstance(v, MappingNode):
        return "a mapping"
    if isinstance(v, SequenceNode):
        return "a list"
    return f"{type(v).__name__} {_short(v)}"


def _suggest(word: str, choices: Iterable[str]) -> str:
    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _parent(path: str) -> str:
    if path.endswith("]"):
        return path[: path.rindex("[")]
    return path.rpartition(".")[0]


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _required(f: dataclasses.Field) -> bool:
    return f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING


def _optional_of(tp: Any) -> tuple[bool, Any]:
    """(accepts None, the type without None) for ``X | None``; (False, tp) otherwise."""
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return len(args) < len(typing.get_args(tp)), args[0]
        raise TypeError(f"unsupported union in model: {tp}")
    return False, tp


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


# ============================================================================ the walker


class _Ctx:
    """One file being read: its name for messages, and the line of every dotted key."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.lines: dict[str, int] = {}       # path -> line of the value (scalar/flow) or key
        self.key_lines: dict[str, int] = {}   # path -> line of the key itself
        self.nodes: dict[str, Node] = {}      # path -> value node
        self.adjust_params: dict[str, float] = {}   # effective adjuster parameters
        self._entries: dict[int, list[tuple[str, Node, Node]]] = {}
        self._constructor = yaml.constructor.SafeConstructor()

    # ---------------------------------------------------------------- errors and lines

    def error(self, path: str, what: str, line: int | None = None) -> ConfigError:
        if line is None:
            line = self.line(path)
        return ConfigError(_one_line(what), file=self.file, line=line, key=path or None)

    def line(self, path: str) -> int | None:
        """The line of ``path``, or of its nearest ancestor that was written in the file."""
        p = path
        while p:
            if p in self.lines:
                return self.lines[p]
            p = _parent(p)
        return self.lines.get("", 1)

    def _record(self, path: str, value: Node, key: Node | None = None) -> None:
        flow = isinstance(value, ScalarNode) or getattr(value, "flow_style", False)
        vline = value.start_mark.line + 1
        kline = key.start_mark.line + 1 if key is not None else vline
        self.lines[path] = vline if flow or key is None else kline
        self.key_lines[path] = kline
        self.nodes[path] = value

    # ---------------------------------------------------------------- scalars

    def scalar(self, node: Node, path: str) -> Any:
        """The Python value of a scalar node (YAML 1.1 safe types)."""
        if not isinstance(node, ScalarNode):
            raise self.error(path, f"expected a single value, got {_describe(node)}")
        try:
            return self._constructor.construct_object(node, deep=True)
        except Exception as e:  # a bad tag or timestamp: still one line, never a traceback
            raise self.error(path, f"cannot read value: {e}") from None

    def number(self, node: Node, path: str, integer: bool = False) -> float | int:
        v = self.scalar(node, path)
        if isinstance(v, str) and not integer and node.style is None:
            # PyYAML reads 1e3 (no dot) as a string; a plain scalar that is a number is one.
            try:
                v = float(v)
            except ValueError:
                pass
        if isinstance(v, bool) or not isinstance(v, int | float):
            want = "an integer" if integer else "a number"
            raise self.error(path, f"expected {want}, got {_describe(v)}")
        if isinstance(v, float):
            if not math.isfinite(v):
                raise self.error(path, f"must be a finite number, got {_num(v)}")
            if integer:
                if not v.is_integer():
                    raise self.error(path, f"expected an integer, got {_describe(v)}")
                return int(v)
        if isinstance(v, int) and not integer:
            try:
                return float(v)
            except OverflowError:
                raise self.error(path, f"number too large: {_short(v)}") from None
        return v

    # ---------------------------------------------------------------- collections

    def entries(self, node: Node, path: str) -> list[tuple[str, Node, Node]]:
        """The (key, key node, value node) of a mapping in file order.

        Rejects non-mappings, non-string keys and duplicate keys; resolves ``<<`` merges.
        """
        if not isinstance(node, MappingNode):
            v = node if not isinstance(node, ScalarNode) else self.scalar(node, path)
            raise self.error(path, f"expected a mapping, got {_describe(v)}")
        cached = self._entries.get(id(node))
        if cached is not None:
            return cached
        seen: dict[str, Node] = {}
        explicit: list[tuple[str, Node, Node]] = []
        has_merge = False
        for knode, vnode in node.value:
            if knode.tag == "tag:yaml.org,2002:merge":
                has_merge = True
                continue
            key = self._key(knode, path)
            sub = _join(path, key)
            if key in seen:
                raise self.error(sub, f"duplicate key {key!r} (first at line "
                                      f"{seen[key].start_mark.line + 1})",
                                 line=knode.start_mark.line + 1)
            seen[key] = knode
            explicit.append((key, knode, vnode))
        result = explicit
        if has_merge:
            try:
                self._constructor.flatten_mapping(node)
            except yaml.YAMLError as e:
                raise self.error(path, f"bad merge (<<): {getattr(e, 'problem', e)}",
                                 line=node.start_mark.line + 1) from None
            merged: dict[str, tuple[str, Node, Node]] = {}
            for knode, vnode in node.value:   # merged keys first, explicit keys win
                key = self._key(knode, path)
                merged[key] = (key, knode, vnode)
            result = list(merged.values())
        self._entries[id(node)] = result
        for key, knode, vnode in result:
            self._record(_join(path, key), vnode, knode)
        return result

    def _key(self, knode: Node, path: str) -> str:
        line = knode.start_mark.line + 1
        if not isinstance(knode, ScalarNode):
            raise self.error(path, f"keys must be plain names, got {_describe(knode)}",
                             line=line)
        k = self.scalar(knode, path)
        if not isinstance(k, str):
            raise self.error(path, f"key {knode.value!r} is read as {_describe(k)}; keys "
                                   f"must be names (quote it: '{knode.value}')", line=line)
        if not k:
            raise self.error(path, "empty key", line=line)
        return k

    def items(self, node: Node, path: str) -> list[Node]:
        if not isinstance(node, SequenceNode):
            v = node if not isinstance(node, ScalarNode) else self.scalar(node, path)
            raise self.error(path, f"expected a list, got {_describe(v)}")
        for i, item in enumerate(node.value):
            self._record(f"{path}[{i}]", item)
        return list(node.value)

    def unknown(self, key: str, path: str, known: Iterable[str], what: str = "key") -> None:
        known = sorted(known)
        hint = _suggest(key, known) or (f" (known: {', '.join(known)})" if known else "")
        raise self.error(_join(path, key), f"unknown {what} {key!r}{hint}",
                         line=self.key_lines.get(_join(path, key)))

    def missing(self, path: str, key: str, node: Node) -> ConfigError:
        line = self.key_lines.get(path, node.start_mark.line + 1)
        where = f" in {path}" if path else ""
        return self.error(_join(path, key), f"missing required key {key!r}{where}", line=line)

    # ---------------------------------------------------------------- typed values

    def build(self, tp: Any, node: Node, path: str) -> Any:
        """Build a value of model type ``tp`` from ``node``, following the type hint."""
        nullable, tp = _optional_of(tp)
        if isinstance(node, ScalarNode) and node.tag == "tag:yaml.org,2002:null":
            if nullable:
                return None
            raise self.error(path, "must not be empty (null)")
        special = _SPECIAL_TYPES.get(tp)
        if special is not None:
            return special(self, node, path)
        if dataclasses.is_dataclass(tp):
            return self.dataclass(tp, node, path)
        if tp is bool:
            v = self.scalar(node, path)
            if not isinstance(v, bool):
                raise self.error(path, f"expected true or false, got {_describe(v)}")
            return v
        if tp is float:
            return self.number(node, path)
        if tp is int:
            return self.number(node, path, integer=True)
        if tp is str:
            v = self.scalar(node, path)
            if not isinstance(v, str):
                raise self.error(path, f"expected a string, got {_describe(v)}")
            return v
        origin, args = typing.get_origin(tp), typing.get_args(tp)
        if origin is tuple:
            items = self.items(node, path)
            if len(items) != len(args):
                raise self.error(path, f"expected a list of {len(args)} values, "
                                       f"got {len(items)}")
            return tuple(self.build(a, n, f"{path}[{i}]")
                         for i, (a, n) in enumerate(zip(args, items, strict=True)))
        if origin is list:
            return [self.build(args[0], n, f"{path}[{i}]")
                    for i, n in enumerate(self.items(node, path))]
        if origin is dict:
            vt = args[1]
            named = dataclasses.is_dataclass(vt) and "name" in {
                f.name for f in dataclasses.fields(vt)}
            out = {}
            for key, _, vnode in self.entries(node, path):
                sub = _join(path, key)
                out[key] = (self.dataclass(vt, vnode, sub, name=key) if named
                            else self.build(vt, vnode, sub))
            return out
        raise TypeError(f"loader cannot map model type {tp!r} at {path}")

    def dataclass(self, cls: type, node: Node, path: str, name: str | None = None,
                  fill: dict[str, Any] | None = None) -> Any:
        """Build dataclass ``cls`` from a mapping: its fields are the YAML keys.

        ``name`` fills a ``name`` field from the enclosing mapping key; ``fill`` gives
        loader-filled fields (``Path`` ones).
        """
        hints = _hints(cls)
        implied = _IMPLIED_FIELDS.get(cls, frozenset())
        fields = {f.name: f for f in dataclasses.fields(cls)
                  if hints[f.name] is not Path and f.name not in implied
                  and not (name is not None and f.name == "name")}
        extra = _EXTRA_KEYS.get(cls, frozenset())
        kwargs: dict[str, Any] = dict(fill or {})
        if name is not None and "name" in hints:
            kwargs["name"] = name
        given = set()
        for key, _, vnode in self.entries(node, path):
            sub = _join(path, key)
            if key in extra:
                continue
            if key not in fields:
                self.unknown(key, path, list(fields) + list(extra))
            given.add(key)
            builder = _FIELD_BUILDERS.get((cls, key))
            if builder is not None:
                kwargs.update(builder(self, vnode, sub))
                continue
            value = self.build(hints[key], vnode, sub)
            self.check_field(cls, key, value, sub)
            kwargs[key] = value
        for fname, f in fields.items():
            if fname not in given and _required(f):
                raise self.missing(path, fname, node)
        return cls(**kwargs)

    def check_field(self, cls: type, fname: str, value: Any, path: str) -> None:
        """Per-field checks from the tables: enumerations, ranges, ``leaf`` import paths."""
        allowed = ENUMS.get((cls, fname))
        if allowed is not None and value not in allowed:
            raise self.error(path, f"must be one of {', '.join(allowed)}, got {value!r}"
                                   f"{_suggest(str(value), allowed)}")
        rng = RANGES.get((cls, fname))
        if rng is not None and value is not None and not rng.contains(value):
            raise self.error(path, f"must be {rng.describe()}, got {_num(value)}")
        if fname == "leaf" and value is not None:
            self.check_leaf(value, path)

    def check_leaf(self, spec: str, path: str) -> None:
        """A leaf is ``package.module:Class``; import it now so a typo fails at load time."""
        if not LEAF_RE.match(spec):
            raise self.error(path, f"must be an import path 'package.module:Class', "
                                   f"got {_short(spec)}")
        mod_name, cls_name = spec.split(":")
        try:
            mod = import_near(mod_name, Path(self.file).parent)
        except BaseException as e:  # noqa: BLE001 - any failure of foreign code is one line
            if isinstance(e, KeyboardInterrupt):
                raise
            raise self.error(path, f"cannot import module {mod_name!r} for leaf {spec!r}: "
                                   f"{type(e).__name__}: {e}") from None
        obj = getattr(mod, cls_name, None)
        if obj is None:
            raise self.error(path, f"module {mod_name!r} has no class {cls_name!r} "
                                   f"(leaf {spec!r}){_suggest(cls_name, dir(mod))}")
        if not inspect.isclass(obj):
            raise self.error(path, f"{spec!r} is a {type(obj).__name__}, not a class")


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
    for key, _, vnode in ctx.entries(inner, kpath):
        if key not in known:
            ctx.unknown(key, kpath, known)
        values[key] = ctx.build(hints[key], vnode, _join(kpath, key))
    for key in SHAPE_KINDS[kind]:
        if key not in values:
            raise ctx.missing(kpath, key, inner)
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
    """``{part, pose, pickable, mirrored?, <feature>: [lo, hi], ...}``."""
    hints = _hints(VisionClass)
    plain = {f.name: f for f in dataclasses.fields(VisionClass) if f.name != "ranges"}
    kwargs: dict[str, Any] = {}
    ranges: dict[str, tuple[float, float]] = {}
    for key, _, vnode in ctx.entries(node, path):
        sub = _join(path, key)
        if key in plain:
            kwargs[key] = ctx.build(hints[key], vnode, sub)
        elif key in FEATURES:
            lo, hi = ctx.build(tuple[float, float], vnode, sub)
            if lo > hi:
                raise ctx.error(sub, f"range [lo, hi] has lo > hi: [{_num(lo)}, {_num(hi)}]")
            ranges[key] = (lo, hi)
        else:
            ctx.unknown(key, path, list(plain) + list(FEATURES), what="class key or feature")
    for fname, f in plain.items():
        if fname not in kwargs and _required(f):
            raise ctx.missing(path, fname, node)
    if not ranges:
        raise ctx.error(path, f"a class needs at least one feature range "
                              f"({', '.join(FEATURES)})")
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
    for name, n in counts.items():
        if n < 0:
            raise ctx.error(_join(ppath, name), f"count must be >= 0, got {n}")
    if not any(n > 0 for n in counts.values()):
        raise ctx.error(ppath, "the hopper needs at least one part with a count > 0")
    return {"hopper": counts}


def _build_conveyors(ctx: _Ctx, node: Node, path: str) -> dict[str, Any]:
    """Cell ``conveyors``: ``horizontal`` and ``incline`` belts, ``return: {transit_s}``."""
    conveyors = CellSpec(name="", path=Path()).conveyors   # the model's defaults
    out: dict[str, Any] = {}
    for key, _, vnode in ctx.entries(node, path):
        sub = _join(path, key)
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
    out["conveyors"] = conveyors
    return out


_SPECIAL_TYPES: dict[type, Callable[[_Ctx, Node, str], Any]] = {
    Shape: _build_shape,
    VisionClass: _build_vision_class,
}
_FIELD_BUILDERS: dict[tuple[type, str], Callable[[_Ctx, Node, str], dict[str, Any]]] = {
    (Scenario, "hopper"): _build_hopper,
    (CellSpec, "conveyors"): _build_conveyors,
    (FaultPlanSpec, "rates"): build_rates,
}

# ============================================================================ files


def _compose(path: Path, ctx: _Ctx) -> MappingNode:
    """Read and parse one file into its root mapping node; every failure is a ConfigError."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError("file not found", file=ctx.file) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, not a YAML file", file=ctx.file) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"not UTF-8 text ({e.reason} at byte {e.start})",
                          file=ctx.file) from None
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", file=ctx.file) from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        what = e.problem or e.context or "syntax error"
        if e.context and e.problem and e.context_mark is not None:
            what += f" ({e.context} at line {e.context_mark.line + 1})"
        raise ConfigError(_one_line(f"YAML syntax error: {what}"), file=ctx.file,
                          line=mark.line + 1 if mark else None) from None
    except yaml.reader.ReaderError as e:
        line = text[: e.position].count("\n") + 1 if isinstance(e.position, int) else None
        raise ConfigError(f"unacceptable character #x{e.character:04x} in the file",
                          file=ctx.file, line=line) from None
    except yaml.YAMLError as e:
        raise ConfigError(_one_line(f"YAML error: {e}"), file=ctx.file) from None
    except RecursionError:
        raise ConfigError("YAML nested too deeply", file=ctx.file) from None
    if root is None:
        raise ConfigError("file is empty; expected a mapping of keys", file=ctx.file, line=1)
    if not isinstance(root, MappingNode):
        v = root if not isinstance(root, ScalarNode) else ctx.scalar(root, "")
        raise ConfigError(f"expected a mapping of keys at the top, got {_describe(v)}",
                          file=ctx.file, line=root.start_mark.line + 1)
    ctx.lines[""] = root.start_mark.line + 1
    return root


def _load_cell(path: Path, calibration_files: bool = True) -> tuple[CellSpec, _Ctx]:
    ctx = _Ctx(str(path))
    root = _compose(path, ctx)
    cell = ctx.dataclass(CellSpec, root, "", fill={"path": path})
    _check_cell(cell, ctx)
    if calibration_files:
        from ..calibration.files import apply_calibration_file  # local: avoids a cycle
        cell = apply_calibration_file(cell, line=ctx.line("camera.calibration_file"))
    return cell, ctx


def load_cell(path: str | Path, calibration_files: bool = True) -> CellSpec:
    """Load and validate a cell description (the hardware a scenario runs on).

    ``calibration_files=False`` leaves out the calibration files the cell names: the
    calibration commands load the cell before they write those files."""
    return _load_cell(Path(path), calibration_files)[0]


def load_scenario(path: str | Path, cell: str | Path | None = None,
                  overlay: str | Path | None = None) -> tuple[Scenario, CellSpec]:
    """Load a scenario and its cell, validated against each other.

    The scenario's ``cell:`` key is relative to the scenario file; ``cell`` overrides it so
    one scenario runs unchanged on the simulated cell, emulators or a real cell. An
    ``overlay`` file is merged over the scenario before validation (scenario/overlay.py).
    """
    path = Path(path)
    ctx = _Ctx(str(path))
    root = _compose(path, ctx)
    if overlay is not None:
        from .overlay import apply_overlay
        root = apply_overlay(root, overlay, ctx, _compose, _Ctx)
    cell_node = next((v for k, _, v in ctx.entries(root, "") if k == "cell"), None)
    if cell is not None:
        cell_path = Path(cell)
        if cell_node is not None:
            ctx.build(str, cell_node, "cell")
    elif cell_node is None:
        raise ctx.error("cell", "missing required key 'cell' (the cell description file, "
                                "relative to this scenario)", line=root.start_mark.line + 1)
    else:
        rel = ctx.build(str, cell_node, "cell")
        if not rel.strip():
            raise ctx.error("cell", "must name a cell file, got an empty string")
        cell_path = Path(os.path.normpath(path.parent / rel))
        if not cell_path.is_file():
            what = "is not a file" if cell_path.exists() else "not found"
            raise ctx.error("cell", f"cell file {rel!r} {what} (looked for {cell_path})")
    scenario = ctx.dataclass(Scenario, root, "", fill={"path": path, "cell_path": cell_path})
    _check_scenario(scenario, ctx)
    cell_spec, _ = _load_cell(cell_path)
    _check_against_cell(scenario, ctx, cell_spec)
    return scenario, cell_spec


def load_fault_plan(path: str | Path) -> FaultPlanSpec:
    """Load and validate a fault plan for the simulated cell (``docs/faults.md``)."""
    path = Path(path)
    ctx = _Ctx(str(path))
    root = _compose(path, ctx)
    plan = ctx.dataclass(FaultPlanSpec, root, "", fill={"path": path})
    check_fault_plan(plan, ctx)
    return plan


def check_files(paths: list[str]) -> list[str]:
    """Validate scenario and cell files for ``feeder check``: one error line per bad file.

    A file with a ``parts`` or ``cell`` key is a scenario (and its cell is checked with it);
    anything else is read as a cell description.
    """
    errors = []
    for p in paths:
        try:
            if _looks_like_scenario(Path(p)):
                load_scenario(p)
            else:
                load_cell(p)
        except ConfigError as e:
            errors.append(str(e))
    return errors


def _looks_like_scenario(path: Path) -> bool:
    try:
        root = yaml.compose(path.read_text(encoding="utf-8"), Loader=yaml.SafeLoader)
    except Exception:  # noqa: BLE001 - the real load reports it properly
        return False
    if not isinstance(root, MappingNode):
        return False
    keys = {k.value for k, _ in root.value if isinstance(k, ScalarNode)}
    return bool(keys & {"parts", "cell"})


# ============================================================================ semantics


def _check_cell(cell: CellSpec, ctx: _Ctx) -> None:
    """Cross-field checks inside a cell description."""
    r = cell.robot
    if r.inner_reach_mm >= r.reach_mm:
        raise ctx.error("robot.inner_reach_mm", f"must be < robot.reach_mm "
                                                f"({_num(r.reach_mm)}), got "
                                                f"{_num(r.inner_reach_mm)}")
    t = cell.camera.target
    if t is not None:
        if min(t.board) < 2:
            raise ctx.error("camera.target.board", f"needs at least 2 points per row and 2 "
                                                   f"rows, got {t.board[0]}x{t.board[1]}")
        if t.kind == "charuco" and t.marker_mm >= t.pitch_mm:
            raise ctx.error("camera.target.marker_mm", f"must be < pitch_mm "
                                                       f"({_num(t.pitch_mm)}), got "
                                                       f"{_num(t.marker_mm)}")
    e = cell.encoder
    if e.robot_start >= 2 ** e.robot_bits:
        raise ctx.error("encoder.robot_start", f"must be < 2**robot_bits "
                                               f"({2 ** e.robot_bits}), got {e.robot_start}")
    _check_galil(cell, ctx)


# Galil wiring (issue 15; docs/real-cell.md): I/O bits start at 1, the input monitor reports
# inputs 1-16, and the DMC-21x3 latches each axis from its own fixed input.
GALIL_MAX_INPUT = 16
GALIL_MAX_OUTPUT = 16


def _check_galil(cell: CellSpec, ctx: _Ctx) -> None:
    g = cell.galil
    for name, sig in cell.io.items():
        if sig.controller != "galil":
            continue
        top = GALIL_MAX_INPUT if sig.dir == "in" else GALIL_MAX_OUTPUT
        if not 1 <= sig.bit <= top:
            raise ctx.error(f"io.{name}.bit", f"Galil {'inputs' if sig.dir == 'in' else 'outputs'}"
                                              f" are numbered 1-{top}, got {sig.bit}")
    axis = str(g.latch_axis).upper()
    if len(axis) != 1 or axis not in "ABCDEFGH":
        raise ctx.error("galil.latch_axis", f"one axis letter A-H, got {g.latch_axis!r}")
    fixed = "ABCDEFGH".index(axis) + 1
    if g.latch_input is not None and g.latch_input != fixed:
        raise ctx.error("galil.latch_input", f"the DMC-21x3 latches axis {axis} from input "
                                             f"{fixed} only (fixed per axis); wire the camera "
                                             f"trigger there, got {g.latch_input}")


def _check_scenario(sc: Scenario, ctx: _Ctx) -> None:
    """Checks that need more than one field of the scenario (but not the cell)."""
    for pname, part in sc.parts.items():
        ppath = f"parts.{pname}.poses"
        if not part.poses:
            raise ctx.error(ppath, "a part needs at least one stable pose")
        total = math.fsum(p.probability for p in part.poses.values())
        if abs(total - 1.0) > PROBABILITY_TOLERANCE:
            terms = " + ".join(f"{n} {_num(p.probability)}" for n, p in part.poses.items())
            raise ctx.error(ppath, f"pose probabilities must sum to 1, got {total:.6g} "
                                   f"({terms})")
        if not any(p.pickable for p in part.poses.values()):
            raise ctx.error(ppath, "a part needs at least one pickable pose")
    if not sc.parts:
        raise ctx.error("parts", "a scenario needs at least one part")
    th = sc.vision.threshold
    if th.block_px % 2 == 0:
        raise ctx.error("vision.threshold.block_px", f"must be odd, got {th.block_px}")
    if th.method == "adaptive" and th.c >= 0:
        raise ctx.error("vision.threshold.c",
                        f"must be < 0, got {_num(th.c)}: as in OpenCV the threshold is the "
                        f"local mean minus c, so c >= 0 makes flat belt foreground "
                        f"(c: -{_num(abs(th.c) or 5)} puts it {_num(abs(th.c) or 5)} grey "
                        f"levels above the mean)")
    for i, vc in enumerate(sc.vision.classes):
        cpath = f"vision.classes[{i}]"
        if vc.part not in sc.parts:
            raise ctx.error(f"{cpath}.part", f"unknown part {vc.part!r}"
                                             f"{_suggest(vc.part, sc.parts)}; parts: "
                                             f"{', '.join(sc.parts)}")
        poses = sc.parts[vc.part].poses
        if vc.pose not in poses:
            raise ctx.error(f"{cpath}.pose", f"part {vc.part!r} has no pose {vc.pose!r}"
                                             f"{_suggest(vc.pose, poses)}; poses: "
                                             f"{', '.join(poses)}")
    for name in sc.hopper:
        if name not in sc.parts:
            raise ctx.error(f"hopper.parts.{name}", f"unknown part {name!r}"
                                                    f"{_suggest(name, sc.parts)}; parts: "
                                                    f"{', '.join(sc.parts)}",
                            line=ctx.key_lines.get(f"hopper.parts.{name}"))
    for i, name in enumerate(sc.retrieve.sequence):
        if name not in sc.parts:
            raise ctx.error(f"retrieve.sequence[{i}]", f"unknown part {name!r}"
                                                       f"{_suggest(name, sc.parts)}")
    ctx.adjust_params = _check_adjust(sc.adjust, ctx)


def _check_adjust(adj: AdjustParams, ctx: _Ctx) -> dict[str, float]:
    """Check ``adjust.params`` against the tables, then let the adjuster check itself.

    Returns the parameters the adjuster will really use (its defaults filled in) so that
    speeds left at a default are still checked against the cell.
    """
    allowed = ADJUST_PARAMS[adj.algorithm]
    for key, v in adj.params.items():
        sub = f"adjust.params.{key}"
        if key not in allowed:
            if not allowed:
                raise ctx.error(sub, f"algorithm {adj.algorithm!r} takes no params, got "
                                     f"{key!r}", line=ctx.key_lines.get(sub))
            ctx.unknown(key, "adjust.params", allowed, what=f"{adj.algorithm} parameter")
        if not allowed[key].contains(v):
            raise ctx.error(sub, f"must be {allowed[key].describe()}, got {_num(v)}")
    cls = ADJUSTERS.get(adj.algorithm)
    effective = dict(cls.PARAMS) if cls is not None else {}
    effective.update(adj.params)
    for algo, small, large, strict in ADJUST_ORDER:
        if algo != adj.algorithm or small not in effective or large not in effective:
            continue
        a, b = effective[small], effective[large]
        if a > b or (strict and a == b):
            given = "" if large in adj.params else " (its default)"
            raise ctx.error(f"adjust.params.{small}",
                            f"must be {'<' if strict else '<='} {large} ({_num(b)}{given}), "
                            f"got {_num(a)}")
    if cls is not None:
        try:
            effective = dict(cls(adj.params).params)
        except AdjusterParamError as e:
            what = str(e).removeprefix(f"{e.key}: ")
            raise ctx.error(f"adjust.params.{e.key}", what) from None
    return effective


def _check_against_cell(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """Checks of the scenario against the cell it runs on (errors name the scenario line)."""
    hmax = cell.conveyors["horizontal"].max_mm_s
    imax = cell.conveyors["incline"].max_mm_s
    pct = sc.present.incline_pct
    cfile = str(cell.path)

    def speed(path: str, v: float, note: str = "") -> None:
        if v > hmax:
            raise ctx.error(path, f"{_num(v)} mm/s{note} is above the horizontal conveyor's "
                                  f"max_mm_s {_num(hmax)} ({cfile})")
        if v * pct / 100.0 > imax:
            raise ctx.error(path, f"{_num(v)} mm/s{note} at incline_pct {_num(pct)} gives "
                                  f"{_num(v * pct / 100.0)} mm/s on the incline, above its "
                                  f"max_mm_s {_num(imax)} ({cfile})")

    h = sc.present.horizontal_mm_s
    if h > hmax:
        speed("present.horizontal_mm_s", h)
    if h * pct / 100.0 > imax:
        raise ctx.error("present.incline_pct", f"incline speed {_num(h)} * {_num(pct)}% = "
                                               f"{_num(h * pct / 100.0)} mm/s is above the "
                                               f"incline conveyor's max_mm_s {_num(imax)} "
                                               f"({cfile})")
    for key, v in ctx.adjust_params.items():   # with the adjuster's defaults filled in
        if key.endswith("_mm_s"):
            speed(f"adjust.params.{key}", v,
                  "" if key in sc.adjust.params else f" (the {sc.adjust.algorithm} default)")

    window = cell.camera.height_px * cell.camera.calibration.mm_per_px
    biggest, size = max(((n, part_size_mm(p)) for n, p in sc.parts.items()),
                        key=lambda t: t[1])
    limit = window - size
    fs = sc.locate.frame_spacing_mm
    if fs >= limit:
        raise ctx.error("locate.frame_spacing_mm",
                        f"must be < {_num(limit)} (camera window {_num(window)} mm along the "
                        f"belt minus the largest part, {biggest!r} {size:.1f} mm), got "
                        f"{_num(fs)}")
