"""The run report: the JSON contract for CI, benchmarks and users comparing settings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from .cell import Cell
from .ticker import Ticker


def _pct(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)), 3) if values else 0.0


def build_report(cell: Cell, ticker: Ticker, *, seed: int, hal: str, sim_seconds: float,
                 feed_seconds: float, wall_seconds: float, interrupted: bool = False
                 ) -> dict[str, Any]:
    s = cell.stats
    retrieved = {name: s.retrieved.get(name, 0) for name in (cell.scenario.parts if cell.scenario
                                                            else {})}
    total = sum(retrieved.values())
    world = getattr(cell.hal, "world", None)
    parts: dict[str, Any] = {
        "retrieved": retrieved,
        "located": s.counts["located"],
        "located_unpickable": s.counts["located_unpickable"],
        "duplicates": s.counts["duplicates"],
        "missed": s.counts["missed"],
        "too_far": s.counts["too_far"],
        "unreachable": s.counts["unreachable"],
        "recirculated": world.counts["recirculated"] if world else None,
        "misoriented": world.counts["misoriented"] if world else None,
        "lost": world.lost() if world else None,
    }
    report: dict[str, Any] = {
        "scenario": cell.scenario.name if cell.scenario else None,
        "cell": cell.cell.name,
        "seed": seed,
        "hal": hal,
        "state": cell.state.value,
        "fault": cell.fault_reason,
        "interrupted": interrupted,
        "sim_seconds": round(sim_seconds, 3),
        "feed_seconds": round(feed_seconds, 3),
        "wall_seconds": round(wall_seconds, 3),
        "parts_per_minute": round(total * 60.0 / feed_seconds, 3) if feed_seconds > 0 else 0.0,
        "parts": parts,
        "faults": dict(s.faults),
        "recoveries": dict(s.recoveries),
        "tick": ticker.stats.summary(),
        "vision": {"frames": s.counts["frames"], "p50_ms": _pct(s.vision_ms, 50),
                   "p99_ms": _pct(s.vision_ms, 99)},
    }
    if world is not None:
        report["world"] = {"census": world.census(), "released": world.counts["released"],
                           "landed_touching": world.counts["landed_touching"],
                           "placed": dict(world.placed_by_type)}
    return report


def write_report(report: dict[str, Any], path: str | Path) -> None:
    Path(path).write_text(json.dumps(report, indent=2) + "\n")
