"""The run report as types: the JSON contract CI reads (``feeder run --report``), published
as a JSON Schema (``feeder schema report``).

``RunReport.to_json()`` is the report's JSON, key for key and in the same order as the
report has always been written; ``RunReport.from_json`` reads one back. A key a run does
not have (the simulated world's counts on a real cell, the kits of a run without kits) is
``ABSENT``: left out of the JSON, which is not the same as ``null`` (a value the run has
but could not compute, such as recirculations per placed part with none placed). Sections
whose inner keys belong to their own modules (the tick statistics, the robot fit, the
world's census, kits, the supply plan, the plate's actions, the part server) are typed as
objects here and described where they are built.
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from dataclasses import dataclass, field
from typing import Any


class _Absent:
    """The marker of a key the report does not have (see the module's docstring)."""

    _one: _Absent | None = None

    def __new__(cls) -> _Absent:
        if cls._one is None:
            cls._one = super().__new__(cls)
        return cls._one

    def __repr__(self) -> str:
        return "ABSENT"

    def __bool__(self) -> bool:
        return False


ABSENT: Any = _Absent()


def _absent() -> Any:
    return field(default=ABSENT)


@dataclass
class Parts:
    """Where the parts went. The keys after ``dropped`` are the simulated world's truth."""

    retrieved: dict[str, int]
    located: int
    located_unpickable: int
    duplicates: int
    missed: int
    too_far: int
    unreachable: int
    recirculated: int | None
    misoriented: int | None
    lost: int | None
    duplicated: int | None
    misplaced: dict[str, int] | None
    dropped: int
    grip_misses: dict[str, int] = _absent()
    supplied: int = _absent()
    shipped: int = _absent()
    scrapped: int = _absent()
    recirculated_per_placed: float | None = _absent()
    accounting: list[Any] = _absent()        # each part the accounting found wrong, named
    # placements the world saw and the cell did not count (world_only), or the cell
    # counted and the world did not see (cell_only), by type: absent when they agree
    outcomes: dict[str, dict[str, int]] = _absent()


@dataclass
class Vision:
    frames: int
    p50_ms: float
    p99_ms: float
    no_match: dict[str, Any] | None
    gripper_blocked: int


@dataclass
class RunReport:
    """One run of ``feeder run``: what it fed, against which bounds, and what went wrong."""

    scenario: str | None
    cell: str
    seed: int
    hal: str
    state: str
    fault: str | None
    interrupted: bool
    sim_seconds: float
    feed_seconds: float
    wall_seconds: float
    parts_per_minute: float
    robot_bound_ppm: float
    robot_bound_cycle_s: float
    robot_bound_kind: str
    # the selection-aware robot bounds over the simulated world's record (robot_bounds.py);
    # robot_bounds_since_s instead when the record does not cover the run (a changeover)
    robot_bounds_since_s: float = _absent()
    robot_bound_mean_ppm: float | None = _absent()
    robot_bound_mean_cycle_s: float | None = _absent()
    robot_bound_selection_ppm: float = _absent()
    robot_bound_selection_parts: int = _absent()
    supply_bound_ppm: float = _absent()
    inflow_bound_ppm: float = _absent()      # parts enter only by totes (a supply plan)
    inflow_lag_s: float = _absent()
    # parts/min over the selection yardstick's: a ratio, since it is no bound
    of_selection: float = _absent()
    ceiling: str = _absent()
    ceiling_ppm: float = _absent()
    of_ceiling_pct: float | None = _absent()
    parts: Parts = _absent()
    faults: dict[str, int] = _absent()       # device faults (vocabulary.py)
    misses: dict[str, int] = _absent()       # misses the trees retry
    recoveries: dict[str, int] = _absent()
    retried: dict[str, int] = _absent()
    encoder_drift: dict[str, Any] = _absent()
    tick: dict[str, Any] = _absent()
    vision: Vision = _absent()
    kits: dict[str, Any] = _absent()
    plate: dict[str, int] = _absent()
    camera: dict[str, Any] = _absent()       # a camera that counts its frames (pylon)
    robot_model: dict[str, Any] = _absent()  # the model the pick policies learnt
    robot_busy_pct: float | None = _absent()
    robot_time: dict[str, Any] = _absent()
    world: dict[str, Any] = _absent()        # the simulated world's census and counts
    speeds: dict[str, Any] = _absent()
    injected: dict[str, int] = _absent()     # a fault plan's faults, injected
    unseen: dict[str, int] = _absent()       # injected, met by nobody
    watchdog_stops: int = _absent()
    reconnects: dict[str, int] = _absent()   # the drivers' links, per controller
    fault_plan: str = _absent()
    supply: dict[str, Any] = _absent()
    operator: dict[str, Any] = _absent()     # the dashboard's operators (--ui)
    part_server: dict[str, Any] = _absent()  # robots served (--part-server)
    opcua: dict[str, Any] = _absent()        # the OPC UA server's clients (--opcua)

    def to_json(self) -> dict[str, Any]:
        """The report as written: every key it has, in order, none it does not."""
        return _to_json(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> RunReport:
        """A report read back (``json.load`` of a ``--report`` file); a key this version
        does not know is a ``ReportError`` naming it."""
        return _from_json(cls, data, "")

    def update(self, more: dict[str, Any]) -> None:
        """Sections added by name (the plant adapters' ``report()``), each a known key."""
        for k, v in more.items():
            if k not in _FIELDS[RunReport]:
                raise ReportError(f"{k}: not a key of the run report")
            setattr(self, k, v)


class ReportError(ValueError):
    """A run report that does not have the shape of ``RunReport``."""


_FIELDS: dict[type, dict[str, dataclasses.Field]] = {
    c: {f.name: f for f in dataclasses.fields(c)} for c in (Parts, Vision, RunReport)}


def _to_json(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _to_json(getattr(obj, f.name)) for f in dataclasses.fields(obj)
                if getattr(obj, f.name) is not ABSENT}
    return obj


def _from_json(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise ReportError(f"{where or 'report'}: expected an object, got {type(data).__name__}")
    fields = _FIELDS[cls]
    hints = typing.get_type_hints(cls)
    extra = [k for k in data if k not in fields]
    if extra:
        raise ReportError(f"{where + '.' if where else ''}{extra[0]}: not a key of the report")
    kwargs = {}
    for name, f in fields.items():
        if name not in data:
            if f.default is dataclasses.MISSING:
                raise ReportError(f"{where + '.' if where else ''}{name}: missing")
            continue
        tp = hints[name]
        nested = next((t for t in (tp, *typing.get_args(tp)) if t in _FIELDS), None)
        value = data[name]
        kwargs[name] = (_from_json(nested, value, f"{where + '.' if where else ''}{name}")
                        if nested is not None and value is not None else value)
    return cls(**kwargs)


# ------------------------------------------------------------------------------ the schema

def _type_schema(tp: Any) -> dict[str, Any]:
    if tp in _FIELDS:
        return report_schema(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        subs = [_type_schema(a) for a in args if a is not type(None)]
        nullable = type(None) in args
        if len(subs) == 1:
            s = dict(subs[0])
            if nullable and "type" in s:
                s["type"] = [s["type"], "null"]
            elif nullable:
                s = {"anyOf": [s, {"type": "null"}]}
            return s
        return {"anyOf": subs + ([{"type": "null"}] if nullable else [])}
    if tp is Any:
        return {}
    if tp is bool:
        return {"type": "boolean"}
    if tp is int:
        return {"type": "integer"}
    if tp is float:
        return {"type": "number"}
    if tp is str:
        return {"type": "string"}
    if origin is dict or tp is dict:
        out: dict[str, Any] = {"type": "object"}
        if len(args) == 2 and args[1] is not Any:
            out["additionalProperties"] = _type_schema(args[1])
        return out
    if origin is list or tp is list:
        return {"type": "array"}
    raise TypeError(f"no schema for {tp!r}")


def report_schema(cls: type = RunReport) -> dict[str, Any]:
    """The JSON Schema of the report (or of one of its typed sections): every key a report
    may have, the ones every report has required, nothing else allowed."""
    hints = typing.get_type_hints(cls)
    props = {name: _type_schema(hints[name]) for name in _FIELDS[cls]}
    required = [n for n, f in _FIELDS[cls].items() if f.default is dataclasses.MISSING]
    out: dict[str, Any] = {"type": "object", "properties": props, "required": required,
                           "additionalProperties": False}
    if cls is RunReport:
        out = {"$schema": "https://json-schema.org/draft/2020-12/schema",
               "title": "feeder run report", "description": (__doc__ or "").split("\n\n")[0],
               **out}
    return out


CHECK_ENV = "FEEDER_CHECK_REPORTS"


def check_written(report: dict[str, Any]) -> None:
    """With ``FEEDER_CHECK_REPORTS`` set (the test suite sets it, so every report a test
    writes, in its own process or a child's, is checked), the report is validated against
    ``report_schema`` with the ``jsonschema`` package before it is written."""
    if not os.environ.get(CHECK_ENV):
        return
    import jsonschema
    jsonschema.validate(report, report_schema())
    RunReport.from_json(report)
