"""One vocabulary for what went wrong in a run, used by the terminal summary, `feeder report`,
its plot, `feeder replay` and the dashboard.

- a **fault** stops or degrades the cell: a device failed (the robot's servo timed out, a
  controller link dropped, the camera lost a frame, a conveyor stalled, an e-stop) and the
  cell ran without it until a recovery (a branch of the trees, or the operator's reset);
- a **miss** is an ordinary failed attempt the trees simply retry, with nothing to recover: a
  missed grab (the gripper closed on nothing) or a pick refused as out of reach;
- an **alarm** is a fault that stopped the cell until the operator's reset: an e-stop, or
  the cell's own fault state (the OPC UA alarm, docs/plant.md).

The trees count both by kind in one counter (``Stats.faults``); the report splits it with
:func:`split` into ``faults`` and ``misses``, and so does every text that shows them.
tests/core/test_vocabulary.py checks the docs and UI strings keep to these meanings.
"""

from __future__ import annotations

import textwrap
from typing import Any

#: kinds the trees count that are misses, not faults: nothing failed but one attempt
MISS_KINDS = frozenset({"missed_grab", "envelope"})

#: how each kind reads in a summary
WORDS = {"missed_grab": "missed grab", "envelope": "out of reach", "servo_timeout":
         "servo timeout", "comms_lost": "link lost", "grab_failed": "camera frame lost",
         "conveyor": "conveyor", "conveyor_jam": "conveyor jam",
         "card_fault": "conveyor controller fault", "estop": "e-stop",
         "power_off": "robot power off (e-stop or guard)",
         "dropped": "part dropped", "cell": "cell fault"}


def split(counts: dict[str, int] | None) -> tuple[dict[str, int], dict[str, int]]:
    """(faults, misses) of a counter by kind."""
    counts = counts or {}
    faults = {k: v for k, v in counts.items() if k not in MISS_KINDS and v}
    misses = {k: v for k, v in counts.items() if k in MISS_KINDS and v}
    return faults, misses


def _by_kind(counts: dict[str, int]) -> str:
    """``servo timeout 41, link lost 3``: most first."""
    return ", ".join(f"{WORDS.get(k, k.replace('_', ' '))} {v}"
                     for k, v in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def story_text(report: dict[str, Any], indent: str = "  ", width: int = 80) -> str:
    """:func:`story` wrapped to ``width`` columns, each line after the first indented more."""
    return "\n".join(textwrap.fill(line, width, initial_indent=indent,
                                   subsequent_indent=indent + "  ") for line in story(report))


def story(report: dict[str, Any]) -> list[str]:
    """What happened, beyond the parts: faults (injected and recovered), misses, alarms,
    misoriented and scrapped parts; one line each, only what the run had (80 columns)."""
    faults, misses = split(report.get("faults"))      # an older report: both in "faults"
    misses.update(report.get("misses") or {})
    recovered = report.get("recoveries") or {}
    injected = split(report.get("injected"))[0]
    lines = []
    if faults or injected:
        n, r = sum(faults.values()), sum(min(v, faults.get(k, 0)) for k, v in recovered.items())
        inj = f" (injected {sum(injected.values())})" if injected else ""
        kinds = f": {_by_kind(faults)}" if faults else ""
        dog = report.get("watchdog_stops")
        wd = f"; the Galil's watchdog stopped the belts {dog} times" if dog else ""
        links = {k: v for k, v in (report.get("reconnects") or {}).items() if v}
        rc = f"; links reconnected: {_by_kind(links)}" if links else ""
        lines.append(f"faults {n}{inj}, recovered {r}{kinds}{wd}{rc}")
    else:
        lines.append("faults 0")
    if misses:
        lines.append(f"misses {sum(misses.values())} ({_by_kind(misses)}), each retried")
    alarms = alarm_counts(report)
    if alarms:
        lines.append(f"alarms {sum(alarms.values())} ({_by_kind(alarms)})")
    p = report.get("parts") or {}
    extra = [f"{k} {p[k]}" for k in ("misoriented", "scrapped") if p.get(k)]
    if extra:
        lines.append(", ".join(extra))
    return lines


def alarm_counts(report: dict[str, Any]) -> dict[str, int]:
    """The faults that stopped the cell until the operator's reset: e-stops, the arm's power
    lost to one (or to a guard), and the cell's own fault state (the OPC UA alarm, docs/plant.md)."""
    faults = report.get("faults") or {}
    out = {k: faults[k] for k in ("estop", "power_off", "cell") if faults.get(k)}
    if report.get("fault") and "cell" not in out:
        out["cell"] = 1
    return out
