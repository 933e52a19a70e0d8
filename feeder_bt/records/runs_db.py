"""Reading the event log: which runs it holds, their summaries and their time series."""

from __future__ import annotations

import json
import math
import sqlite3
from dataclasses import dataclass
from typing import Any

import numpy as np

from feeder_bt.core.vocabulary import MISS_KINDS, split, story
from feeder_bt.records.eventlog import EventLogError


@dataclass
class Series:
    """One run's time series: samples (every adjust period) and retrieved events."""

    t: np.ndarray
    queue: np.ndarray
    horizontal_mm_s: np.ndarray
    retrieved: np.ndarray                 # cumulative, at each sample
    retrieved_t: dict[str, np.ndarray]    # retrieval times per part type
    faults_t: np.ndarray                  # faults: the cell stopped or ran degraded
    misses_t: np.ndarray                  # misses: a grab or pick retried (vocabulary.py)
    t0: float                             # the run's first event (start command)


def run_ids(conn: sqlite3.Connection, run: int | None = None, last: bool = False) -> list[int]:
    """The runs asked for: one by id, the last one, or all (oldest first)."""
    try:
        ids = [r[0] for r in conn.execute("SELECT id FROM runs ORDER BY id")]
    except sqlite3.Error as e:
        raise EventLogError(f"cannot read the runs: {e}") from None
    if run is not None:
        if run not in ids:
            raise EventLogError(f"no run {run} in this log (runs: {_ranges(ids) or 'none'})")
        return [run]
    if not ids:
        raise EventLogError("the event log holds no runs yet")
    return ids[-1:] if last else ids


def _ranges(ids: list[int]) -> str:
    return f"{ids[0]}..{ids[-1]}" if len(ids) > 1 else ", ".join(map(str, ids))


def summary(conn: sqlite3.Connection, run_id: int) -> dict[str, Any]:
    """The figures of one run: from its final report, or from its events if it has none
    (a run killed before it could write one)."""
    try:
        row = conn.execute("SELECT * FROM runs WHERE id=?", (run_id,)).fetchone()
        report = json.loads(row["report"]) if row["report"] else None
        out: dict[str, Any] = {"run": run_id, "scenario": row["scenario"], "cell": row["cell"],
                               "seed": row["seed"], "hal": row["hal"],
                               "started": row["started"]}
        if report is not None:
            p = report["parts"]
            out.update(state=report["state"], duration_s=report["feed_seconds"],
                       parts_per_minute=report["parts_per_minute"], retrieved=p["retrieved"],
                       located=p["located"], missed=p["missed"], lost=p["lost"],
                       misoriented=p.get("misoriented"), scrapped=p.get("scrapped"),
                       faults=split(report["faults"])[0],
                       misses={**split(report["faults"])[1], **(report.get("misses") or {})},
                       story=story(report))
            if report.get("kits"):
                out["kits"] = {**report["kits"], **kits_by_minute(conn, run_id,
                                                                  report["feed_seconds"])}
            return out
        by_type = dict(conn.execute(
            "SELECT json_extract(data, '$.type'), count(*) FROM events "
            "WHERE run_id=? AND kind='retrieved' GROUP BY 1", (run_id,)).fetchall())
        located, t_end = conn.execute(
            "SELECT sum(kind='located'), max(t) FROM events WHERE run_id=?",
            (run_id,)).fetchone()
        faults = dict(conn.execute(
            "SELECT json_extract(data, '$.kind'), count(*) FROM events "
            "WHERE run_id=? AND kind='fault' GROUP BY 1", (run_id,)).fetchall())
        recovered = dict(conn.execute(
            "SELECT json_extract(data, '$.kind'), count(*) FROM events "
            "WHERE run_id=? AND kind='recovered' GROUP BY 1", (run_id,)).fetchall())
    except (sqlite3.Error, json.JSONDecodeError, KeyError, TypeError) as e:
        raise EventLogError(f"run {run_id}: damaged record ({e})") from None
    total = sum(by_type.values())
    duration = float(t_end or 0.0)
    out.update(state="incomplete", duration_s=round(duration, 3),
               parts_per_minute=round(total * 60.0 / duration, 3) if duration > 0 else 0.0,
               retrieved=by_type, located=int(located or 0), missed=None, lost=None,
               misoriented=None, scrapped=None, faults=split(faults)[0],
               misses=split(faults)[1],
               story=story({"faults": faults, "recoveries": recovered}))
    return out


MAX_BINS = 30          # a kit run's pace in at most this many bins of whole minutes


def kits_by_minute(conn: sqlite3.Connection, run_id: int, feed_s: float
                   ) -> dict[str, Any]:
    """Kits completed in each minute of feeding (from the run's RUNNING), or each few
    minutes past ``MAX_BINS`` minutes (``bin_s``), the last bin perhaps shorter
    (``last_bin_s``): where a kit run lost its pace, at the start (the scarce type not yet
    come round) or later. Nothing for a run with no feeding time."""
    if not isinstance(feed_s, (int, float)) or not 0.0 < feed_s < 1e9:
        return {}
    start = conn.execute("SELECT min(t) FROM events WHERE run_id=? AND kind='state' AND "
                         "json_extract(data, '$.new')='RUNNING'", (run_id,)).fetchone()[0]
    start = float(start or 0.0)
    bin_s = 60.0 * max(1, math.ceil(feed_s / 60.0 / MAX_BINS - 1e-9))
    n = max(1, math.ceil(feed_s / bin_s - 1e-9))
    counts = [0] * n
    for (t,) in conn.execute("SELECT t FROM events WHERE run_id=? AND kind='kit'", (run_id,)):
        counts[min(n - 1, max(0, int((t - start) // bin_s)))] += 1
    return {"bin_s": bin_s, "by_bin": counts, "last_bin_s": round(feed_s - bin_s * (n - 1), 3)}


def series(conn: sqlite3.Connection, run_id: int) -> Series:
    """Samples and retrieval/fault times of one run, as arrays for plotting."""
    try:
        rows = conn.execute("SELECT t, queue, horizontal_mm_s, retrieved FROM samples "
                            "WHERE run_id=? ORDER BY t", (run_id,)).fetchall()
        ret = conn.execute("SELECT t, json_extract(data, '$.type') FROM events "
                           "WHERE run_id=? AND kind='retrieved' ORDER BY t",
                           (run_id,)).fetchall()
        faults, misses = [], []               # a miss is not a fault (vocabulary.py)
        for t, kind in conn.execute("SELECT t, json_extract(data, '$.kind') FROM events "
                                    "WHERE run_id=? AND kind='fault' ORDER BY t", (run_id,)):
            (misses if kind in MISS_KINDS else faults).append(t)
        t0 = conn.execute("SELECT min(t) FROM events WHERE run_id=?", (run_id,)).fetchone()[0]
    except sqlite3.Error as e:
        raise EventLogError(f"run {run_id}: damaged record ({e})") from None
    arr = np.asarray([tuple(r) for r in rows], dtype=float).reshape(-1, 4)
    by_type: dict[str, list[float]] = {}
    for t, kind in ret:
        by_type.setdefault(str(kind), []).append(t)
    return Series(t=arr[:, 0], queue=arr[:, 1], horizontal_mm_s=arr[:, 2],
                  retrieved=arr[:, 3],
                  retrieved_t={k: np.asarray(v) for k, v in by_type.items()},
                  faults_t=np.asarray(faults, dtype=float),
                  misses_t=np.asarray(misses, dtype=float), t0=float(t0 or 0.0))


def rolling_ppm(t: np.ndarray, cumulative: np.ndarray, window_s: float = 60.0,
                t0: float = 0.0, min_span_s: float = 10.0) -> np.ndarray:
    """Parts/min over the last ``window_s`` at each time, from a cumulative count.

    Before a full window has passed, the rate is over the time since ``t0``; NaN while that
    is shorter than ``min_span_s`` (a rate over two seconds says nothing)."""
    t = np.asarray(t, dtype=float)
    c = np.asarray(cumulative, dtype=float)
    if t.size == 0:
        return np.zeros(0)
    start = np.maximum(t - window_s, t0)
    before = np.interp(start, np.concatenate(([t0], t)), np.concatenate(([0.0], c)))
    span = t - start
    with np.errstate(invalid="ignore", divide="ignore"):
        ppm = (c - before) * 60.0 / span
    ppm[span < min_span_s] = np.nan
    return ppm
