"""JSON Schemas of the YAML file kinds, generated from what the loader itself follows.

``feeder schema scenario|cell|faults|supply`` prints one; an editor with a YAML language
server then checks a file as it is typed (docs/getting-started.md). The schema is built from
the same sources as ``loader.py``: the dataclasses and type hints of ``model.py``,
``faults.py`` and ``supply.py`` (a field with a default is an optional key), the tables of allowed values (``ENUMS``,
``RANGES``, ``ADJUST_PARAMS``, ``SHAPE_KINDS``, ``FEATURES``) and the few places where the
YAML is not a mirror of the model (the shape, a vision class, the hopper, the conveyors,
the fault rates). What needs more than one key at a time (pose probabilities summing to 1,
speeds against the cell's conveyors, the camera window) is left to ``feeder check``.

``file_kind`` tells the kinds apart by their top-level keys, for ``feeder check`` and for
the one-line "this is a cell description, not a scenario".
"""

from __future__ import annotations

import dataclasses
import typing
from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, ScalarNode

from feeder_bt.config import loader as L
from feeder_bt.config.faults import _ONLY_FOR, RATE_UNITS, FaultPlanSpec, FaultRate
from feeder_bt.config.supply import SupplyPlanSpec, Totes
from feeder_bt.core.errors import ConfigError
from feeder_bt.core.model import CellSpec, ConveyorSpec, Scenario, Shape, VisionClass
from feeder_bt.vision.features import FEATURES

DRAFT = "http://json-schema.org/draft-07/schema#"

#: The file kinds: the name ``feeder schema`` takes, the model's root class, what to call it.
KINDS: dict[str, tuple[type, str]] = {
    "scenario": (Scenario, "a scenario"),
    "cell": (CellSpec, "a cell description"),
    "faults": (FaultPlanSpec, "a fault plan"),
    "supply": (SupplyPlanSpec, "a supply plan"),
}


# ---------------------------------------------------------------------------- the kinds


def top_keys(kind: str) -> frozenset[str]:
    """The keys the loader accepts at the top of a file of ``kind``."""
    cls = KINDS[kind][0]
    return frozenset(_fields(cls)) | L._EXTRA_KEYS.get(cls, frozenset())


def file_kind(path: str | Path) -> str | None:
    """Which kind a file is, from its top-level keys: the kind whose keys it uses most
    (a scenario on a tie, since ``name`` is both a scenario's and a cell's); None when the
    file cannot be read as a mapping or uses no key of any kind (the loader says why)."""
    try:
        root = yaml.compose(L.read_yaml_text(Path(path), str(path)), Loader=yaml.SafeLoader)
    except Exception:  # noqa: BLE001 - the real load reports it in one line
        return None
    return root_kind(root)


def _top(root: MappingNode) -> set[str]:
    return {k.value for k, _ in root.value if isinstance(k, ScalarNode)}


def root_kind(root: Any) -> str | None:
    """``file_kind`` of a file already composed (its root node)."""
    if not isinstance(root, MappingNode):
        return None
    keys = _top(root)
    score = {kind: len(keys & top_keys(kind) - {"name"}) for kind in KINDS}
    best = max(score.values())
    if best == 0:
        return "scenario" if "name" in keys else None
    return next(kind for kind in KINDS if score[kind] == best)


#: where each kind of file goes, for the line that names a file given in the wrong place
WHERE = {"scenario": "give it as the first argument (feeder run {path})",
         "cell": "give it with --cell after a scenario (feeder run SCENARIO --cell {path})",
         "faults": "give it with --faults after a scenario (feeder run SCENARIO --faults {path})",
         "supply": "give it with --supply after a scenario (feeder run SCENARIO --supply {path})",
         "world": "give it with --world after a scenario (feeder run SCENARIO --world {path})"}


def wrong_kind(root: Any, expected: str) -> str | None:
    """The kind a file's top-level keys say it is, when that is another kind than
    ``expected`` (``scenario``, ``cell``, ``faults``, ``supply`` or ``world``); None when it
    is that kind or its keys say nothing (the loader then lists what is wrong). A file of
    world figures alone (no name, nothing the controller owns) is a world file."""
    from feeder_bt.config.world import NOTES_KEY, WORLD_SECTIONS
    if not isinstance(root, MappingNode):
        return None
    keys = _top(root)
    world = {*WORLD_SECTIONS, NOTES_KEY}
    found = "world" if keys and keys <= world else root_kind(root)
    if found is None or found == expected:
        return None
    if expected == "world" and not keys & (top_keys(found) - world):
        return None        # world figures and a misspelt one: the loader says which
    return found


def wrong_kind_error(root: Any, expected: str, path: str | Path, how: str = "",
                     hint: str | None = None) -> ConfigError | None:
    """The one line for a file of another kind than ``expected`` ("this is a scenario, not
    a cell description: ..."), instead of a line for each key the expected kind lacks;
    ``how`` names the option it was given with, ``hint`` says what to give instead."""
    found = wrong_kind(root, expected)
    if found is None:
        return None
    if hint is None:
        hint = WHERE[found].format(path=path)
    how = f" ({how})" if how else ""
    return ConfigError(f"this is {describe(found)}, not {describe(expected)}{how}: {hint}",
                       file=str(path))


def check_kind(root: Any, expected: str, path: str | Path) -> None:
    """Raise ``wrong_kind_error`` when there is one: the loaders call it on the root."""
    err = wrong_kind_error(root, expected, path)
    if err is not None:
        raise err


def describe(kind: str) -> str:
    if kind == "world":            # laid over a cell file (config/world.py), no root class
        return "a world file"
    return KINDS[kind][1]


# ---------------------------------------------------------------------------- the schema


def schema(kind: str) -> dict[str, Any]:
    """The JSON Schema (draft 7) of one file kind."""
    cls, what = KINDS[kind]
    body = _dataclass(cls)
    return {"$schema": DRAFT, "$id": f"urn:feeder-bt:schema:{kind}",
            "title": f"feeder_bt {kind}", "description": f"{what} for feeder_bt. "
            + (cls.__doc__ or "").strip().split("\n")[0], **body}


def _fields(cls: type) -> dict[str, dataclasses.Field]:
    """The fields of ``cls`` that are YAML keys (as ``_Ctx.dataclass`` takes them)."""
    hints = L._hints(cls)
    implied = L._IMPLIED_FIELDS.get(cls, frozenset())
    return {f.name: f for f in dataclasses.fields(cls)
            if hints[f.name] is not Path and f.name not in implied}


def _dataclass(cls: type, keyed: bool = False) -> dict[str, Any]:
    """An object with one property per field; ``keyed``: its ``name`` is the mapping key."""
    hints = L._hints(cls)
    props: dict[str, Any] = {}
    required: list[str] = []
    for name, f in _fields(cls).items():
        if keyed and name == "name":
            continue
        builder = _FIELD_SCHEMAS.get((cls, name))
        if builder is not None:
            props.update(builder())
            if L._required(f):
                required.append(name)
            continue
        props[name] = _field(cls, name, hints[name], f)
        if L._required(f):
            required.append(name)
    for extra in L._EXTRA_KEYS.get(cls, frozenset()):
        props[extra] = _EXTRA_SCHEMAS[(cls, extra)]
    out: dict[str, Any] = {"type": "object", "properties": props,
                           "additionalProperties": False}
    if required:
        out["required"] = required
    doc = (cls.__doc__ or "").strip()
    if doc and not doc.startswith(f"{cls.__name__}("):
        out["description"] = " ".join(doc.split("\n\n")[0].split())
    if cls is L.AdjustParams:
        out["allOf"] = _adjust_rules()
    return out


def _field(cls: type, name: str, tp: Any, f: dataclasses.Field | None = None) -> dict[str, Any]:
    s = _type(tp)
    allowed = L.ENUMS.get((cls, name))
    if allowed is not None:
        s = {**s, "enum": list(allowed)}
    rng = L.RANGES.get((cls, name))
    if rng is not None:
        s = _with_range(s, rng)
    if name == "leaf":
        s = {"anyOf": [{"type": "string", "pattern": L.LEAF_RE.pattern}, {"type": "null"}],
             "description": "a class used instead: 'package.module:Class'"}
    default = _default(f) if f is not None else None
    if default is not None:
        s = {**s, "default": default}
    if cls is L.AdjustParams and name == "params":
        s = {"type": "object", "additionalProperties": {"type": "number"}}
    return s


def _type(tp: Any) -> dict[str, Any]:
    """The schema of a model type, as ``_Ctx.build`` reads it."""
    nullable, tp = L._optional_of(tp)
    if nullable:
        return {"anyOf": [_type(tp), {"type": "null"}]}
    special = _SPECIAL_SCHEMAS.get(tp)
    if special is not None:
        return special()
    if dataclasses.is_dataclass(tp):
        return _dataclass(tp)
    if tp is bool:
        return {"type": "boolean"}
    if tp is float:
        return {"type": "number"}
    if tp is int:
        return {"type": "integer"}
    if tp is str:
        return {"type": "string"}
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is tuple:
        return {"type": "array", "items": [_type(a) for a in args], "additionalItems": False,
                "minItems": len(args), "maxItems": len(args)}
    if origin is list:
        return {"type": "array", "items": _type(args[0])}
    if origin is dict:
        vt = args[1]
        named = dataclasses.is_dataclass(vt) and "name" in {
            f.name for f in dataclasses.fields(vt)}
        return {"type": "object",
                "additionalProperties": _dataclass(vt, keyed=True) if named else _type(vt)}
    raise TypeError(f"schema cannot map model type {tp!r}")


def _with_range(s: dict[str, Any], rng: L.Range) -> dict[str, Any]:
    s = dict(s)
    if rng.lo is not None:
        s["exclusiveMinimum" if rng.lo_open else "minimum"] = rng.lo
    if rng.hi is not None:
        s["exclusiveMaximum" if rng.hi_open else "maximum"] = rng.hi
    return s


def _default(f: dataclasses.Field) -> Any:
    v = f.default if f.default is not dataclasses.MISSING else None
    if isinstance(v, tuple):
        v = list(v)
    return v if isinstance(v, bool | int | float | str | list) else None


# ---------------------------------------------------------------------------- special cases


def _shape() -> dict[str, Any]:
    """``{disc: {diameter_mm, hole_mm?}}`` | ``{rect: {size_mm: [w, h]}}`` |
    ``{polygon: {points_mm, holes_mm?}}``."""
    hints = L._hints(Shape)
    inner = {"diameter_mm": {"type": "number", "exclusiveMinimum": 0},
             "hole_mm": {"type": "number", "minimum": 0,
                         "description": "a round hole in the middle (a washer), < diameter_mm"},
             "size_mm": {"type": "array", "items": [{"type": "number", "exclusiveMinimum": 0}] * 2,
                         "additionalItems": False, "minItems": 2, "maxItems": 2},
             "points_mm": {**_type(hints["points_mm"]), "minItems": 3},
             "holes_mm": {"type": "array", "items": {**_type(hints["points_mm"]), "minItems": 3},
                          "description": "polygon holes, each a list of [x, y] points"}}
    return {"type": "object", "description": "the part's outline: exactly one shape kind",
            "minProperties": 1, "maxProperties": 1, "additionalProperties": False,
            "properties": {kind: {"type": "object", "additionalProperties": False,
                                  "required": list(keys),
                                  "properties": {k: inner[k] for k in
                                                 keys + L.SHAPE_OPTIONAL.get(kind, ())}}
                           for kind, keys in L.SHAPE_KINDS.items()}}


def _vision_class() -> dict[str, Any]:
    """``{part, pose, pickable, mirrored?, <feature>: [lo, hi], ...}``."""
    hints = L._hints(VisionClass)
    props = {f.name: _type(hints[f.name]) for f in dataclasses.fields(VisionClass)
             if f.name != "ranges"}
    props["orientation"] = {"anyOf": [{"enum": list(L.ENUMS[(VisionClass, "orientation")])},
                                      {"type": "null"}],
                            "description": "this class's own orientation (default the "
                                           "recipe's)"}
    pair = {"type": "array", "items": [{"type": "number"}] * 2, "additionalItems": False,
            "minItems": 2, "maxItems": 2}
    for feat, what in FEATURES.items():
        props[feat] = {**pair, "description": f"[lo, hi] of the {what}"}
    required = [f.name for f in dataclasses.fields(VisionClass)
                if f.name != "ranges" and L._required(f)]
    return {"type": "object", "properties": props, "additionalProperties": False,
            "required": required,
            "anyOf": [{"required": [f]} for f in (*FEATURES, "rulers")],
            "description": "a feature box: a blob whose features all fall in the ranges is "
                           "this part in this pose (at least one feature range, or rulers)"}


def _hopper() -> dict[str, Any]:
    return {"hopper": {"type": "object", "required": ["parts"], "additionalProperties": False,
                       "properties": {"parts": {
                           "type": "object", "minProperties": 1,
                           "additionalProperties": {"type": "integer", "minimum": 0},
                           "description": "how many of each part the hopper holds"}}}}


def _conveyors() -> dict[str, Any]:
    belt = _dataclass(ConveyorSpec)
    transit = _with_range({"type": "number"}, L.RANGES[(CellSpec, "return_transit_s")])
    props = {name: belt for name in L.CONVEYOR_NAMES}
    props["return"] = {"type": "object", "additionalProperties": False,
                       "properties": {"transit_s": transit}}
    return {"conveyors": {"type": "object", "properties": props,
                          "additionalProperties": False}}


def _rates() -> dict[str, Any]:
    hints = L._hints(FaultRate)
    fields = {f.name: f for f in dataclasses.fields(FaultRate)}
    kinds = {}
    for kind, unit in RATE_UNITS.items():
        keys = [unit] + [k for k, only in _ONLY_FOR.items() if kind in only and k in fields]
        kinds[kind] = {"type": "object", "required": [unit], "additionalProperties": False,
                       "properties": {k: _field(FaultRate, k, hints[k], fields[k])
                                      for k in keys}}
        kinds[kind]["properties"][unit] = _with_range(
            {"type": "number"}, L.RANGES[(FaultRate, unit)])
    return {"rates": {"type": "object", "properties": kinds, "additionalProperties": False}}


def _adjust_rules() -> list[dict[str, Any]]:
    """``adjust.params`` by algorithm (each takes its own keys; ``none`` takes none)."""
    rules = []
    for algo, params in L.ADJUST_PARAMS.items():
        cond: dict[str, Any] = {"properties": {"algorithm": {"const": algo}}}
        if algo != "none":
            cond["required"] = ["algorithm"]
        rules.append({"if": cond, "then": {"properties": {"params": {
            "type": "object", "additionalProperties": False,
            "properties": {k: _with_range({"type": "number"}, r)
                           for k, r in params.items()}}}}})
    return rules


def _by_type(key: str, what: str, integer: bool = False) -> Any:
    """A supply plan's mapping of part type to a count or a weight, each >= 0."""
    value = {"type": "integer" if integer else "number", "minimum": 0}
    body: dict[str, Any] = {"type": "object", "additionalProperties": value,
                            "description": what}
    if key == "start":
        body = {"anyOf": [body, {"type": "null"}]}
    return lambda: {key: body}


_SPECIAL_SCHEMAS = {Shape: _shape, VisionClass: _vision_class}
_FIELD_SCHEMAS = {(Scenario, "hopper"): _hopper, (CellSpec, "conveyors"): _conveyors,
                  (FaultPlanSpec, "rates"): _rates,
                  (SupplyPlanSpec, "start"): _by_type(
                      "start", "the hopper at the start: parts by type", integer=True),
                  (Totes, "mix"): _by_type("mix", "a tote's parts by type, as weights"),
                  (Totes, "drift_to"): _by_type(
                      "drift_to", "the mix the totes drift to, as weights")}
_EXTRA_SCHEMAS = {(Scenario, "cell"): {
    "type": "string", "minLength": 1,
    "description": "the cell description file, relative to this scenario"}}
