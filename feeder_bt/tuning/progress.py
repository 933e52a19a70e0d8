"""The progress display of ``feeder tune``: a rich progress bar on a terminal (stderr), one
line per trial otherwise (a log, CI, a pipe)."""

from __future__ import annotations

import sys
from typing import Any, TextIO

from feeder_bt.tuning.search import TrialResult, describe

AS_WRITTEN = " (the scenario as written)"


class TrialProgress:
    """Context manager; ``start(done, total)`` then ``trial(result)`` after each trial."""

    def __init__(self, where: str, out: TextIO | None = None) -> None:
        self.where = where
        self.out = out or sys.stderr
        self.tty = self.out.isatty()
        self.best: tuple[float, int] | None = None
        self.done = 0
        self.total = 0
        self._bar: Any = None
        self._task: Any = None

    def __enter__(self) -> TrialProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        if self._bar is not None:
            self._bar.stop()

    def start(self, done: int, total: int, best: tuple[float, int] | None = None) -> None:
        self.done, self.total, self.best = done, total, best
        if done:
            print(f"tune: continuing the study at trial {done}/{total}", file=self.out)
        if not self.tty:
            print(f"tune: {max(total - done, 0)} trials on {self.where}", file=self.out,
                  flush=True)
            return
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )
        self._bar = Progress(TextColumn("tune"), BarColumn(), MofNCompleteColumn(),
                             TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(),
                             TextColumn("{task.fields[best]}"),
                             console=Console(file=self.out), transient=False)
        self._task = self._bar.add_task("tune", total=total, completed=done,
                                        best=f"on {self.where}" + (
                                            f"; best {best[0]:.2f}" if best else ""))
        self._bar.start()

    def trial(self, r: TrialResult) -> None:
        self.done += 1
        name = describe(r.overlay) + (AS_WRITTEN if r.start else "")
        if r.value is not None and r.recirc is not None:
            name += f"; recirculated {r.recirc:.2f} per placed" + (
                "" if r.feasible else ", over --max-recirc")
        if r.pruned_at is not None:         # a rung's score, not a value: never the best
            name += f"; pruned after {r.duration:g} s x {len(r.per_seed)} seed"
        elif (r.value is not None and r.feasible
                and (self.best is None or r.value > self.best[0])):
            self.best = (r.value, r.number)
        best = (f"best {self.best[0]:.2f} {r.unit} (trial {self.best[1]})"
                if self.best else "no trial completed yet")
        if self._bar is not None:
            self._bar.update(self._task, completed=self.done, best=best)
            what = (f"{r.value:.2f} {r.unit}" if r.value is not None
                    else f"failed: {r.error}")
            self._bar.console.print(f"trial {r.number}: {what}  {name}",
                                    highlight=False, markup=False)
            return
        what = (f"{r.value:.2f} {r.unit} (seeds {', '.join(f'{v:.2f}' for v in r.per_seed)})"
                if r.value is not None else f"failed: {r.error}")
        print(f"trial {r.number} [{self.done}/{self.total}]: {what}  {name}; "
              f"{best}", file=self.out, flush=True)
