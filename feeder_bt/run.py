"""The main job: load a scenario on a cell, feed for a while, stop in order, report."""

from __future__ import annotations

import argparse
import signal
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from .cell import Cell, CellState
from .clock import RealClock, SimClock
from .eventlog import EventLog
from .hal.factory import make_hal
from .report import build_report, write_report
from .scenario import load_scenario
from .scenario.model import Scenario
from .ticker import Ticker
from .view import LiveView, Progress

STOP_GRACE_S = 30.0        # clock time allowed for the clean-up tree after a stop
DEFAULT_DB = "runs/feeder.db"   # the command line's event log unless --db / --no-db


@dataclass
class RunOptions:
    scenario: str
    cell: str | None = None
    duration: float = 60.0
    fast: bool = False
    seed: int = 1
    report: str | None = None
    hal: str = "sim"
    view: str = "unicode"          # unicode | ascii | none
    skip_idle: bool = True
    db: str | None = None          # SQLite event log; None or "" for none (CLI: DEFAULT_DB)


def add_db_options(parser: argparse.ArgumentParser) -> None:
    """``--db FILE`` / ``--no-db`` for ``feeder run`` (every CLI run is logged by default)."""
    parser.add_argument("--db", metavar="FILE.db", default=DEFAULT_DB,
                        help=f"SQLite event log for `feeder report` (default {DEFAULT_DB})")
    parser.add_argument("--no-db", dest="db", action="store_const", const=None,
                        help="do not write the event log")


def _start_log(log: EventLog, opts: RunOptions, scenario: Scenario, cell: Cell) -> None:
    log.start_run({**asdict(opts), "scenario_file": opts.scenario, "cell_file": opts.cell,
                   "scenario": scenario.name, "cell": cell.cell.name,
                   "adjust": {"algorithm": scenario.adjust.algorithm,
                              "params": scenario.adjust.params}})
    log.attach(cell)


class _StopRequest:
    """Ctrl-C / SIGTERM ask for an orderly stop at the next tick boundary; a second Ctrl-C
    interrupts at once (the clean-up still runs)."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum, frame) -> None:
        if self.requested and signum == signal.SIGINT:
            raise KeyboardInterrupt
        self.requested = True


def run_job(opts: RunOptions) -> dict[str, Any]:
    scenario, cell_spec = load_scenario(opts.scenario, opts.cell)
    log = EventLog(opts.db) if opts.db else None      # a bad --db fails before the HAL opens
    hal, clock = make_hal(opts.hal, scenario, cell_spec, opts.seed)
    if not isinstance(clock, SimClock):
        clock = RealClock()
    cell = Cell(cell_spec, hal, clock)
    if log:
        _start_log(log, opts, scenario, cell)
    ticker = Ticker(cell, fast=opts.fast, skip_idle=opts.skip_idle)
    show: LiveView | Progress | None = None
    if opts.fast:
        show = Progress(cell, opts.duration)
    elif opts.view != "none":
        show = LiveView(cell, fmt=opts.view)
    every = show.update if show else None
    if log:     # after each tick: the view, then the log's batch (cheap when not due)
        every = (lambda: (show.update(), log.periodic_flush())) if show else log.periodic_flush

    request = _StopRequest()
    old = {sig: signal.signal(sig, request) for sig in (signal.SIGINT, signal.SIGTERM)}
    wall0 = time.monotonic()
    interrupted = False
    t_start = clock.now()
    t_stop = t_start
    try:
        cell.load(scenario)
        cell.start()
        try:
            ticker.run(until=t_start + opts.duration,
                       stop=lambda: request.requested
                       or cell.state in (CellState.FAULT, CellState.STOPPED),
                       every=every)
        except KeyboardInterrupt:
            pass
        interrupted = request.requested
        t_stop = clock.now()
        cell.stop()
        if isinstance(clock, SimClock):   # no need to watch the clean-up in real time
            ticker.fast, ticker.skip_idle = True, opts.skip_idle
        ticker.run(until=clock.now() + STOP_GRACE_S,
                   stop=lambda: cell.state in (CellState.STOPPED, CellState.FAULT))
        if show:
            show.update(force=True)
            if isinstance(show, Progress):
                show.close()
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)
        hal.close()
        if log:
            log.flush()               # even when interrupted: nothing buffered is lost
    report = build_report(cell, ticker, seed=opts.seed, hal=opts.hal,
                          sim_seconds=clock.now() - t_start, feed_seconds=t_stop - t_start,
                          wall_seconds=time.monotonic() - wall0, interrupted=interrupted)
    if opts.report:
        Path(opts.report).parent.mkdir(parents=True, exist_ok=True)
        write_report(report, opts.report)
    if log:
        log.finish(report)
        log.close()
    return report
