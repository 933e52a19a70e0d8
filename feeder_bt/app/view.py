"""What the terminal shows while a job runs: the live trees with node statuses and the
cell's figures (real time), or a progress bar (fast runs).

The live view fits the terminal whatever its size (``rich`` redraws it in place): the
header, the status lines and the line saying what the cell waits for always come first, and
the trees get the rows left, folded to their running branches when the whole trees do not
fit. On a pipe it prints a status line every 10 s of clock time instead.
"""

from __future__ import annotations

import shutil
import signal
import sys
import textwrap
import time
from collections.abc import Callable
from typing import TextIO

import py_trees
from py_trees.common import Status

from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.figures import figures

CLEAR = "\x1b[H\x1b[J"
MIN_ROWS = 6                 # below this the view shows only the header and status lines


def status_fields(cell: Cell, feed_seconds: float | None = None
                  ) -> tuple[list[str], list[str]]:
    """The status in two groups of fields: the state and the output; then the vision and
    the speeds. Each group is one line of under 80 columns for any realistic run."""
    f = figures(cell, feed_seconds)
    by_type = ", ".join(f"{k} {v}" for k, v in cell.stats.retrieved.items())
    kinds = f" ({by_type})" if by_type and len(cell.stats.retrieved) > 1 else ""
    first = [f"{f['state']:<8} t {f['t']:6.1f} s", f"retrieved {f['retrieved']}{kinds}",
             f"{f['ppm']:.1f} parts/min", f"queue {f['queue']}"]
    if cell.cell.presentation == "plate":    # no belts: what the plate has done instead
        second = [f"located {f['located']}", f"missed {f['missed']}",
                  "plate " + (plate_actions(cell.stats.counts) or "-"),
                  f"robot {f['robot']:.0f}%"]
        return first, second
    second = [f"located {f['located']}", f"missed {f['missed']}", f"too far {f['too_far']}",
              f"belt {f['horizontal']:.0f} mm/s", f"incline {f['incline']:.0f}%",
              f"robot {f['robot']:.0f}%"]
    return first, second


def plate_actions(counts: dict[str, int]) -> str:
    """The plate's actions so far, e.g. "dispense 7, feed forward 4, flip 50" (the
    report's ``plate`` section, without smart feeding's count of decisions)."""
    return ", ".join(f"{k[len('plate_'):].replace('_', ' ')} {v}"
                     for k, v in sorted(counts.items())
                     if k.startswith("plate_") and k != "plate_decisions" and v)


def status_lines(cell: Cell, feed_seconds: float | None = None, width: int = 1000
                 ) -> list[str]:
    """The status lines for a terminal ``width`` wide: two, or more in a narrow one."""
    return [line for group in status_fields(cell, feed_seconds) for line in _pack(group, width)]


def status_line(cell: Cell, feed_seconds: float | None = None) -> str:
    """The whole status as one line (for a pipe or a log)."""
    return "  ".join("  ".join(group) for group in status_fields(cell, feed_seconds))


def _pack(fields: list[str], width: int, sep: str = "  ") -> list[str]:
    """Fields joined by ``sep`` into lines of at most ``width`` (a field is never split,
    only cut when it alone is wider)."""
    lines: list[str] = []
    for field in fields:
        if lines and len(lines[-1]) + len(sep) + len(field) <= width:
            lines[-1] += sep + field
        else:
            lines.append(_fit(field, width))
    return lines


def waiting_for(cell: Cell) -> str:
    """What the cell is waiting for, while that is the news: before the first part is
    placed (a lenses run spends its first ~20 s filling the belt), when paused or faulted."""
    s, now = cell.stats, cell.clock.now()
    since = f"{now - s.started_at:.0f} s" if s.started_at is not None else ""
    state = cell.state
    if state is CellState.FAULT:
        return f"FAULT: {cell.fault_reason or 'unknown'} (an operator must reset the cell)"
    if state is CellState.FAULTING:
        return f"faulted: {cell.fault_reason or 'unknown'}; stopping the cell in order"
    if state is CellState.STOPPING:
        return "stopping the cell in order: trees halted, conveyors and robot to rest"
    if state is CellState.PAUSED:
        return "paused by an operator"
    if state is CellState.STOPPED:
        return "" if s.started_at is not None else "waiting for an operator to start"
    if state is CellState.STARTING:
        return f"setting the cell up (robot home, conveyors, camera): {since}"
    if s.total_retrieved == 0:
        if s.counts["located"] == 0:
            return f"waiting for the first parts to reach the camera: {since}"
        return (f"waiting for the first parts to reach the robot: {since} "
                f"({s.counts['located']} located)")
    return ""


# ------------------------------------------------------------------------ tree folding

_ASCII = {Status.SUCCESS: "o", Status.FAILURE: "x", Status.RUNNING: "*", Status.INVALID: "-"}
_UNICODE = {Status.SUCCESS: "✓", Status.FAILURE: "✕", Status.RUNNING: "*",
            Status.INVALID: "-"}


#: what the node-kind glyphs mean (py_trees' own, also in `feeder tree`): one line each
LEGEND = ("/_/ parallel  {o} [o] selector  {-} [-] sequence  -^- decorator  --> leaf",
          "{ } keeps its running child across ticks, [ ] starts again from the first")
STATUS_LEGEND = "[*] running  [✓] success  [✕] failure  [-] not ticked"


def _kind(node: py_trees.behaviour.Behaviour) -> str:
    if isinstance(node, py_trees.composites.Parallel):
        return "/_/"
    if isinstance(node, py_trees.composites.Sequence):
        return "{-}" if node.memory else "[-]"
    if isinstance(node, py_trees.composites.Selector):
        return "{o}" if node.memory else "[o]"
    if isinstance(node, py_trees.decorators.Decorator):
        return "-^-"
    return "-->"


def _size(node: py_trees.behaviour.Behaviour) -> int:
    return sum(1 for _ in node.iterate()) - 1


def tree_lines(root: py_trees.behaviour.Behaviour, rows: int, fmt: str = "unicode"
               ) -> list[str]:
    """The tree in at most ``rows`` lines: whole if it fits; else folded to the running
    branches (a running node shows its children, any other node is one line); else only
    the running paths under the trees' roots; else cut, saying how many lines are left
    out. A line ``(+N)`` has N nodes folded under it."""
    if rows <= 0:
        return []
    marks = _ASCII if fmt == "ascii" else _UNICODE

    def running(node: py_trees.behaviour.Behaviour) -> bool:
        return node.status is Status.RUNNING

    def draw(expand: Callable[[py_trees.behaviour.Behaviour, int], bool],
             keep: Callable[[py_trees.behaviour.Behaviour, int], bool]) -> list[str]:
        out: list[str] = []

        def walk(node: py_trees.behaviour.Behaviour, depth: int) -> None:
            children = list(node.children)
            shown = [c for c in children if keep(c, depth + 1)] if expand(node, depth) else []
            hidden = sum(1 + _size(c) for c in children if c not in shown)
            more = f" (+{hidden})" if hidden else ""
            out.append(f"{'    ' * depth}{_kind(node)} {node.name} [{marks[node.status]}]{more}")
            for c in shown:
                walk(c, depth + 1)

        walk(root, 0)
        return out

    everything = lambda node, depth: True                              # noqa: E731
    top_or_running = lambda node, depth: depth == 0 or running(node)   # noqa: E731
    for lines in (lambda: draw(everything, everything),
                  lambda: draw(top_or_running, everything),
                  lambda: draw(top_or_running, lambda n, d: d <= 1 or running(n))):
        drawn = lines()
        if len(drawn) <= rows:
            return drawn
    if rows == 1:
        return [drawn[0]]
    return drawn[: rows - 1] + [f"… {len(drawn) - rows + 1} more lines"]


# ------------------------------------------------------------------------ the live view


class LiveView:
    """Redraws in place on a terminal at ``hz``, fitted to the terminal; on a pipe prints a
    status line every 10 s of clock time.

    ``feed_seconds`` gives the run's feeding time as the report counts it (see ``figures``);
    ``note`` is a line under the header (the operator UI's address)."""

    def __init__(self, cell: Cell, fmt: str = "unicode", hz: float = 4.0,
                 out: TextIO | None = None,
                 feed_seconds: Callable[[], float] | None = None) -> None:
        from rich.console import Console

        self.cell, self.fmt, self.period = cell, fmt, 1.0 / hz
        self.out = out or sys.stdout
        self.feed_seconds = feed_seconds
        self.note = ""
        self.console = Console(file=self.out, highlight=False, emoji=False)
        self.tty = self.console.is_terminal and not self.console.is_dumb_terminal
        self.next_wall = 0.0
        self.next_sim = 0.0
        self.live = None
        self._resized = False
        self._old_winch = None

    # ------------------------------------------------------------------ drawing
    def _feed(self) -> float | None:
        return self.feed_seconds() if self.feed_seconds is not None else None

    def lines(self, width: int, height: int) -> list[str]:
        """The screen as lines of at most ``width`` characters, at most ``height`` of them:
        header and status first, then the waiting line, the trees, the latest events.
        With ``fmt`` ascii, only ASCII characters (for a terminal that shows no more)."""
        out = self._lines(width, height)
        return [s.translate(_TO_ASCII) for s in out] if self.fmt == "ascii" else out

    def _lines(self, width: int, height: int) -> list[str]:
        cell = self.cell
        name = cell.scenario.name if cell.scenario else "-"
        head = _pack([f"feeder_bt · {name} on {cell.cell.name}",
                      "Ctrl-C stops the cell in order"], width, sep=" · ")[:2]
        head += status_lines(cell, self._feed(), width)
        for extra in (self.note, waiting_for(cell)):
            if extra:
                head += textwrap.wrap(extra, width, max_lines=2, placeholder=" …")
        if height <= len(head):
            return head[: max(height, 2)]
        rest = height - len(head) - 1              # a blank line under the header
        body: list[str] = []
        if cell.root is not None and rest > 0:
            events = [f"{e.t:8.1f} s  {e.kind:<10} {_data(e.data)}"
                      for e in list(cell.stats.events)[-4:]]
            trees = tree_lines(cell.root, rest, self.fmt)
            if rest - len(trees) >= 3:             # room: what the glyphs and marks mean
                trees += ["", LEGEND[0] + "  ·  " + STATUS_LEGEND]
            spare = rest - len(trees) - 1
            body = trees + ([""] + events[-spare:] if spare > 0 and events else [])
        return head + [""] + [_fit(s, width) for s in body]

    def screen(self, width: int = 100, height: int = 1000) -> str:
        return "\n".join(self.lines(width, height))

    def _renderable(self, spare: int = 0):
        from rich.text import Text

        width, height = self.console.size
        text = Text("\n".join(self.lines(width, max(height - 1 - spare, 2))),
                    no_wrap=True, overflow="crop")
        text.highlight_regex(r"(?m)^(RUNNING|STARTING)\b", "bold green")
        text.highlight_regex(r"(?m)^(STOPP\w+|PAUSED)\b", "bold yellow")
        text.highlight_regex(r"(?m)^FAULT: .*$|^FAULT\w*\b", "bold red")
        text.highlight_regex(r"\[\*\]", "bold yellow")
        text.highlight_regex(r"\[(✕|x)\]", "red")
        return text

    # ------------------------------------------------------------------ the loop
    def update(self, force: bool = False) -> None:
        if self.tty:
            wall = time.monotonic()
            if force or self._resized or wall >= self.next_wall:
                self.next_wall = wall + self.period
                self._resized = False
                self._draw()
        else:
            now = self.cell.clock.now()
            if force or now >= self.next_sim:
                self.next_sim = now + 10.0
                print(status_line(self.cell, self._feed()), file=self.out, flush=True)

    def _draw(self, spare: int = 0) -> None:
        from rich.live import Live

        if self.live is None:
            self.live = Live(console=self.console, auto_refresh=False, transient=False,
                             vertical_overflow="crop", redirect_stdout=False,
                             redirect_stderr=False)
            self.live.start()
            self._watch_resize()
        self.live.update(self._renderable(spare), refresh=True)

    def _watch_resize(self) -> None:
        """Redraw at the next tick when the terminal is resized (not only at ``hz``)."""
        if not hasattr(signal, "SIGWINCH"):
            return
        try:
            self._old_winch = signal.signal(signal.SIGWINCH, self._on_resize)
        except ValueError:          # not the main thread: the next periodic redraw fits
            self._old_winch = None

    def _on_resize(self, signum, frame) -> None:
        self._resized = True

    def close(self, spare: int = 4) -> None:
        """The last screen, leaving ``spare`` rows for the summary under it."""
        if self.live is None:
            return
        self._draw(spare)
        self.live.stop()
        self.live = None
        if self._old_winch is not None:
            signal.signal(signal.SIGWINCH, self._old_winch)
            self._old_winch = None


_TO_ASCII = str.maketrans({"·": "-", "…": "~", "²": "2"})


def _fit(text: str, width: int) -> str:
    return text if len(text) <= width else text[: max(width - 1, 0)] + "…"


def _data(data: dict) -> str:
    return " ".join(f"{k}={v}" for k, v in data.items())


class Progress:
    """A progress bar for fast runs (stderr), fitted to the terminal's width; a line every
    10 % when not a terminal."""

    def __init__(self, cell: Cell, duration: float, out: TextIO | None = None,
                 feed_seconds: Callable[[], float] | None = None) -> None:
        self.cell, self.duration = cell, max(duration, 1e-9)
        self.out = out or sys.stderr
        self.tty = self.out.isatty()
        self.feed_seconds = feed_seconds
        self.next_wall = 0.0
        self.next_tenth = 1

    def update(self, force: bool = False) -> None:
        """Called after every tick; the line is formatted only when it is shown (5 times a
        second on a terminal, every tenth of the run otherwise): formatting it every tick
        cost about 5 % of a fast run."""
        frac = min(1.0, max(0.0, self.cell.clock.now() / self.duration))
        if self.tty:
            wall = time.monotonic()
            if not (force or wall >= self.next_wall):
                return
            self.next_wall = wall + 0.2
            text = self._text(frac)
            width = shutil.get_terminal_size((80, 24)).columns
            bar_w = max(0, min(30, width - len(text) - 4))
            bar = f"[{'#' * int(frac * bar_w):<{bar_w}}] " if bar_w >= 5 else ""
            self.out.write(f"\r{_fit(bar + text, width - 1)}\x1b[K")
            self.out.flush()
        elif force or frac * 10 >= self.next_tenth:
            self.next_tenth = int(frac * 10) + 1
            print(self._text(frac), file=self.out, flush=True)

    def _text(self, frac: float) -> str:
        f = figures(self.cell, self.feed_seconds() if self.feed_seconds else None)
        return (f"{frac * 100:5.1f}%  sim {self.cell.clock.now():5.0f}/{self.duration:.0f} s  "
                f"retrieved {f['retrieved']}  {f['ppm']:.1f} parts/min  queue {f['queue']}")

    def close(self, spare: int = 0) -> None:
        if self.tty:
            self.out.write("\n")
            self.out.flush()
