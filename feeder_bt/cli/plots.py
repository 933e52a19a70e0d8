"""Plots of a run in the manner of thesis Figure 8-3: conveyor speed and queue length
against time, with the throughput they buy (parts/min over a rolling window)."""

from __future__ import annotations

import json
import sqlite3
from typing import Any

import numpy as np

from feeder_bt.records.runs_db import rolling_ppm, series, summary

WINDOW_S = 60.0


def plot_run(conn: sqlite3.Connection, run_id: int, window_s: float = WINDOW_S) -> Any:
    """Three stacked panels sharing the time axis; returns the matplotlib Figure (Agg, never
    a window) so that callers save it and tests can read its axes."""
    from matplotlib.figure import Figure  # not pyplot: no display, no global state

    s = series(conn, run_id)
    info = summary(conn, run_id)
    params = _adjust_params(conn, run_id)
    fig = Figure(figsize=(10, 8), layout="constrained")
    ax_speed, ax_queue, ax_ppm = fig.subplots(3, 1, sharex=True)
    fig.suptitle(f"{info['scenario']} on {info['cell']}: run {run_id}, seed {info['seed']} — "
                 f"{info['parts_per_minute']:.1f} parts/min over "
                 f"{info['duration_s']:.0f} s")

    ax_speed.plot(s.t, s.horizontal_mm_s, color="tab:blue", label="horizontal conveyor")
    for name, style in (("max_mm_s", "--"), ("median_mm_s", "-."), ("min_mm_s", ":")):
        if isinstance(params.get(name), int | float):
            ax_speed.axhline(params[name], color="grey", linestyle=style, linewidth=1,
                             label=f"adjuster {name.split('_')[0]} ({params[name]:g} mm/s)")
    ax_speed.set_title("Horizontal conveyor speed")
    ax_speed.set_ylabel("speed (mm/s)")

    ax_queue.plot(s.t, s.queue, color="tab:orange", label="parts queue")
    for name, style in (("high", "--"), ("low", ":")):
        if isinstance(params.get(name), int | float):
            ax_queue.axhline(params[name], color="grey", linestyle=style, linewidth=1,
                             label=f"{name} water mark ({params[name]:g})")
    ax_queue.set_title("Queue length")
    ax_queue.set_ylabel("queue (parts)")

    ax_ppm.plot(s.t, rolling_ppm(s.t, s.retrieved, window_s, s.t0), color="tab:green",
                label=f"all parts ({window_s:.0f} s rolling)")
    if len(s.retrieved_t) > 1:                 # mixed feeding: one line per part type
        for kind, times in sorted(s.retrieved_t.items()):
            ax_ppm.plot(s.t, rolling_ppm(s.t, np.searchsorted(times, s.t, side="right"),
                                         window_s, s.t0), linewidth=1, label=kind)
    for i, tf in enumerate(s.faults_t):           # faults and misses: vocabulary.py
        ax_ppm.axvline(tf, color="tab:red", linewidth=0.8, alpha=0.6,
                       label="fault" if i == 0 else None)
    if s.misses_t.size:                           # a retried grab: a tick, not a line
        ax_ppm.plot(s.misses_t, np.zeros_like(s.misses_t), linestyle="none", marker="|",
                    markersize=8, color="tab:grey", label="miss (retried)")
    ax_ppm.set_title("Throughput")
    ax_ppm.set_ylabel("parts/min")
    ax_ppm.set_xlabel("time (s)")
    ax_ppm.set_ylim(bottom=0)

    for ax in (ax_speed, ax_queue, ax_ppm):
        ax.grid(True, alpha=0.3)
        ax.legend(loc="best", fontsize="small")
    if s.t.size == 0:
        ax_speed.text(0.5, 0.5, "no samples in this run", transform=ax_speed.transAxes,
                      ha="center")
    return fig


def _adjust_params(conn: sqlite3.Connection, run_id: int) -> dict[str, Any]:
    """The adjuster's parameters the run was started with: its speed limits and water marks
    are drawn as reference lines, as in Figure 8-3."""
    row = conn.execute("SELECT options FROM runs WHERE id=?", (run_id,)).fetchone()
    try:
        params = (json.loads(row[0] or "{}").get("adjust") or {}).get("params") or {}
    except (ValueError, TypeError, AttributeError):
        return {}
    return params if isinstance(params, dict) else {}
