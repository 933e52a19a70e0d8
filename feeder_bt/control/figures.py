"""The cell's figures and trees as text: one formula for the terminal view, the dashboard's
status and the summary, so that each shows the same parts/min."""

from __future__ import annotations

import py_trees

from feeder_bt.behaviours.keys import SPEEDS
from feeder_bt.control.cell import Cell


def tree_text(root: py_trees.behaviour.Behaviour, fmt: str = "unicode") -> str:
    """The whole tree with statuses (the operator UI's text view)."""
    if fmt == "ascii":
        return py_trees.display.ascii_tree(root, show_status=True)
    return py_trees.display.unicode_tree(root, show_status=True)


def figures(cell: Cell, feed_seconds: float | None = None) -> dict[str, float | int | str]:
    """The cell's figures for a status line. ``feed_seconds`` is the run's feeding time as
    its report counts it, so that the view's parts/min is the report's; without it, the time
    since the statistics started."""
    s = cell.stats
    now = cell.clock.now()
    if feed_seconds is None:
        feed_seconds = 0.0 if s.started_at is None else now - s.started_at
    board = cell.board
    return {
        "state": cell.state.value,
        "scenario": cell.scenario.name if cell.scenario else "-",
        "t": now,
        "retrieved": s.total_retrieved,
        "ppm": ppm(s.total_retrieved, feed_seconds),
        "located": s.counts["located"],
        "missed": s.counts["missed"],
        "too_far": s.counts["too_far"],
        "queue": len(cell.ctx.queue) if cell.ctx else 0,
        "horizontal": board.get(SPEEDS.HORIZONTAL, 0.0),
        "incline": board.get(SPEEDS.INCLINE, 0.0),
        "robot": board.get(SPEEDS.ROBOT, 0.0),
    }


def ppm(retrieved: int, feed_seconds: float) -> float:
    """Parts per minute of feeding: the one formula of the view, the summary and the report."""
    return round(retrieved * 60.0 / feed_seconds, 3) if feed_seconds > 0 else 0.0
