"""What the terminal shows while a job runs: the live trees with node statuses and the
cell's figures (real time), or a progress bar (fast runs)."""

from __future__ import annotations

import sys
import time
from typing import TextIO

import py_trees

from .cell import Cell

CLEAR = "\x1b[H\x1b[J"


def tree_text(root: py_trees.behaviour.Behaviour, fmt: str = "unicode") -> str:
    if fmt == "ascii":
        return py_trees.display.ascii_tree(root, show_status=True)
    return py_trees.display.unicode_tree(root, show_status=True)


def figures(cell: Cell) -> dict[str, float | int | str]:
    s = cell.stats
    now = cell.clock.now()
    start = now if s.started_at is None else s.started_at
    minutes = max((now - start) / 60.0, 1e-9)
    speeds = py_trees.blackboard.Blackboard.storage
    return {
        "state": cell.state.value,
        "scenario": cell.scenario.name if cell.scenario else "-",
        "t": now,
        "retrieved": s.total_retrieved,
        "ppm": s.total_retrieved / minutes if s.started_at is not None else 0.0,
        "located": s.counts["located"],
        "missed": s.counts["missed"],
        "too_far": s.counts["too_far"],
        "queue": len(cell.ctx.queue) if cell.ctx else 0,
        "horizontal": speeds.get("/speeds/horizontal_mm_s", 0.0),
        "incline": speeds.get("/speeds/incline_pct", 0.0),
        "robot": speeds.get("/speeds/robot_speed_pct", 0.0),
    }


def status_line(cell: Cell) -> str:
    f = figures(cell)
    by_type = ", ".join(f"{k} {v}" for k, v in cell.stats.retrieved.items()) or "0"
    return (f"{f['state']:<8} t={f['t']:8.1f}s  retrieved {f['retrieved']} ({by_type})  "
            f"{f['ppm']:5.1f}/min  located {f['located']}  missed {f['missed']}  "
            f"too far {f['too_far']}  queue {f['queue']}  "
            f"belt {f['horizontal']:.0f} mm/s  incline {f['incline']:.0f}%  "
            f"robot {f['robot']:.0f}%")


class LiveView:
    """Redraws in place on a terminal at ``hz``; on a pipe prints a status line now and then."""

    def __init__(self, cell: Cell, fmt: str = "unicode", hz: float = 4.0,
                 out: TextIO | None = None) -> None:
        self.cell, self.fmt, self.period = cell, fmt, 1.0 / hz
        self.out = out or sys.stdout
        self.tty = self.out.isatty()
        self.next_wall = 0.0
        self.next_sim = 0.0

    def update(self, force: bool = False) -> None:
        if self.tty:
            wall = time.monotonic()
            if force or wall >= self.next_wall:
                self.next_wall = wall + self.period
                self.out.write(CLEAR + self.screen() + "\n")
                self.out.flush()
        else:
            now = self.cell.clock.now()
            if force or now >= self.next_sim:
                self.next_sim = now + 10.0
                print(status_line(self.cell), file=self.out, flush=True)

    def screen(self) -> str:
        cell = self.cell
        parts = [f"feeder_bt — {cell.scenario.name if cell.scenario else '-'} on {cell.cell.name}"
                 f"   (Ctrl-C stops the cell in order)", status_line(cell), ""]
        if cell.root is not None:
            parts.append(tree_text(cell.root, self.fmt))
        events = list(cell.stats.events)[-6:]
        if events:
            parts.append("")
            parts += [f"  {e.t:8.2f}s {e.kind:<10} {e.data}" for e in events]
        return "\n".join(parts)


class Progress:
    """A progress bar for fast runs (stderr); a line every 10 % when not a terminal."""

    def __init__(self, cell: Cell, duration: float, out: TextIO | None = None) -> None:
        self.cell, self.duration = cell, max(duration, 1e-9)
        self.out = out or sys.stderr
        self.tty = self.out.isatty()
        self.next_wall = 0.0
        self.next_tenth = 1

    def update(self, force: bool = False) -> None:
        frac = min(1.0, max(0.0, self.cell.clock.now() / self.duration))
        f = figures(self.cell)
        text = (f"{frac * 100:5.1f}%  sim {self.cell.clock.now():7.0f}/{self.duration:.0f} s  "
                f"retrieved {f['retrieved']}  {f['ppm']:5.1f}/min  queue {f['queue']}")
        if self.tty:
            wall = time.monotonic()
            if force or wall >= self.next_wall:
                self.next_wall = wall + 0.2
                bar = "#" * int(frac * 30)
                self.out.write(f"\r[{bar:<30}] {text}\x1b[K")
                self.out.flush()
        elif force or frac * 10 >= self.next_tenth:
            self.next_tenth = int(frac * 10) + 1
            print(text, file=self.out, flush=True)

    def close(self) -> None:
        if self.tty:
            self.out.write("\n")
            self.out.flush()
