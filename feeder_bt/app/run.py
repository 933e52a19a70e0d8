"""The main job: load a scenario on a cell, feed for a while, stop in order, report."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from feeder_bt.analysis.report import build_report, write_report
from feeder_bt.app.factory import make_hal
from feeder_bt.app.view import LiveView, Progress
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import RealClock, SimClock
from feeder_bt.core.errors import ConfigError, FeederError
from feeder_bt.core.model import Scenario
from feeder_bt.core.outputs import check_output_file
from feeder_bt.records.eventlog import EventLog

STOP_GRACE_S = 30.0        # clock time allowed for the clean-up tree after a stop
DEFAULT_DB = "runs/feeder.db"   # the command line's event log unless --db / --no-db


@dataclass
class RunOptions:
    scenario: str
    cell: str | None = None
    duration: float | None = 60.0  # clock seconds; None: until Ctrl-C (the --ui default)
    fast: bool = False
    seed: int = 1
    report: str | None = None
    hal: str = "sim"
    view: str = "unicode"          # unicode | ascii | none
    skip_idle: bool = True
    db: str | None = None          # SQLite event log; None or "" for none (CLI: DEFAULT_DB)
    ui: str | None = None          # "HOST:PORT": serve the operator UI (docs/operator-ui.md)
    users: str | None = None       # the UI's users file (default: feeder_bt.control.users)
    start: bool | None = None      # start feeding at once; None: yes, unless --ui
    faults: str | None = None      # a fault plan (docs/faults.md) for the simulated cell
    supply: str | None = None      # a supply plan (docs/supply.md) for the simulated cell
    plant: Any = None              # PlantOptions: --part-server / --opcua (docs/plant.md)
    overlay: str | None = None     # a partial scenario merged over it (feeder tune --out)
    world: str | None = None       # the simulated cell's truth (docs/simulator.md, "World")


def add_db_options(parser: argparse.ArgumentParser) -> None:
    """``--db FILE`` / ``--no-db`` for ``feeder run`` (every CLI run is logged by default)."""
    parser.add_argument("--db", metavar="FILE.db", default=DEFAULT_DB,
                        help=f"SQLite event log for `feeder report` (default {DEFAULT_DB})")
    parser.add_argument("--no-db", dest="db", action="store_const", const=None,
                        help="do not write the event log")


def add_ui_options(parser: argparse.ArgumentParser) -> None:
    """``--ui [HOST:PORT]``, ``--users FILE``, ``--start`` for ``feeder run``."""
    from feeder_bt.control.users import default_path
    from feeder_bt.ui import DEFAULT_BIND, parse_bind

    def bind(text: str) -> str:
        parse_bind(text)                 # one-line usage error now, not after the HAL opens
        return text

    parser.add_argument("--ui", nargs="?", const=DEFAULT_BIND, type=bind, metavar="HOST:PORT",
                        help=f"serve the operator UI while the cell runs (default {DEFAULT_BIND}"
                             "; port 0 picks a free one); the cell then waits STOPPED for an "
                             "operator and the run lasts until Ctrl-C unless --duration")
    parser.add_argument("--users", metavar="FILE",
                        help=f"with --ui: the users file (default {default_path()})")
    parser.add_argument("--start", action="store_true", default=None,
                        help="with --ui: start feeding at once instead of waiting for an "
                             "operator")


# ------------------------------------------------------------------ plant adapters
def add_plant_options(parser: argparse.ArgumentParser) -> None:
    """``--part-server [HOST:]PORT`` (docs/part-server.md) and ``--opcua [HOST:]PORT``
    (docs/plant.md) for ``feeder run``."""
    parser.add_argument("--part-server", metavar="[HOST:]PORT", nargs="?", const="7600",
                        help="serve parts to robots over TCP (default 127.0.0.1:7600); on "
                             "the simulated cell its robot runs a program using the "
                             "reference client")
    parser.add_argument("--no-sim-robot", dest="sim_robot", action="store_false",
                        help="with --part-server on the simulated cell: no simulated robot "
                             "program (an outside client only talks to the server)")
    parser.add_argument("--robots", metavar="FILE",
                        help="with --part-server: the robots file naming the robots that "
                             "may take parts (a secret each, or their addresses); without "
                             "it only this machine is served (docs/part-server.md)")
    parser.add_argument("--sim-robot-port", metavar="[HOST:]PORT", nargs="?", const="7601",
                        help="with --part-server --no-sim-robot on the simulated cell: an "
                             "outside program moves the simulated robot over this port "
                             "(loopback; default 127.0.0.1:7601; docs/part-server.md)")
    parser.add_argument("--opcua", metavar="[HOST:]PORT", nargs="?", const="4840",
                        help="serve the cell over OPC UA at opc.tcp://HOST:PORT/feeder "
                             "(default 127.0.0.1:4840)")
    parser.add_argument("--opcua-insecure", action="store_true",
                        help="with --opcua: also an unsecured endpoint (loopback only; "
                             "for tests)")
    parser.add_argument("--opcua-pki", metavar="DIR",
                        help="with --opcua: where the server's certificate is kept (made "
                             "on first start)")


def plant_options(args: argparse.Namespace) -> Any:
    """The ``PlantOptions`` of parsed ``feeder run`` arguments (None: no adapter)."""
    if not getattr(args, "part_server", None) and not getattr(args, "opcua", None):
        return None
    from feeder_bt.plant.options import PlantOptions
    return PlantOptions(part_server=args.part_server, sim_robot=args.sim_robot,
                        robots=getattr(args, "robots", None),
                        sim_robot_port=getattr(args, "sim_robot_port", None),
                        opcua=args.opcua, opcua_users=args.users,
                        opcua_insecure=args.opcua_insecure, opcua_pki=args.opcua_pki)


def _check_opcua(opts: RunOptions) -> None:
    """Before the HAL opens: the users file names somebody, and one control token."""
    if opts.ui:
        raise FeederError("--ui and --opcua each keep their own control token: serve one "
                          "of them per run, so that one user at a time controls the cell")
    from feeder_bt.ui.app import check_users
    check_users(opts.plant.opcua_users)


def _open_plant(opts: RunOptions, cell: Cell, scenario: Scenario):
    """The part server / OPC UA adapters of this run, opened (None: none asked for)."""
    if opts.plant is None:
        return None
    from feeder_bt.plant.adapters import PlantAdapters
    plant = PlantAdapters(cell, opts.plant, opts.scenario, opts.cell or scenario.cell_path,
                          fast=opts.fast)
    try:
        plant.open()
    except BaseException:       # e.g. the OPC UA port is taken: the part server closes too
        plant.close()
        raise
    return plant


class _FeedSpan:
    """With --ui the operator starts and stops the cell: the report's feed time is the time
    spent between starts and the stops (or faults) that ended them, over the starts the
    cell's statistics cover (the cell keeps counting when the same scenario restarts)."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        self.stats: object = None
        self.done = 0.0                  # closed spans
        self.since: float | None = None  # the open span's start
        cell.listeners.append(self._on_state)

    def _on_state(self, old: CellState, new: CellState) -> None:
        now = self.cell.clock.now()
        if new is CellState.STARTING:
            if self.cell.stats is not self.stats:       # fresh statistics: fresh time
                self.stats, self.done = self.cell.stats, 0.0
            self.since = now
        elif new in (CellState.STOPPING, CellState.FAULTING, CellState.FAULT,
                     CellState.STOPPED) and self.since is not None:
            self.done += now - self.since
            self.since = None

    def seconds(self, t_end: float) -> float:
        return self.done + (t_end - self.since if self.since is not None else 0.0)


def _chain(*fns: Callable[[], None] | None) -> Callable[[], None] | None:
    """One after-tick callback calling each of ``fns`` in order."""
    todo = [f for f in fns if f is not None]
    if len(todo) <= 1:
        return todo[0] if todo else None

    def each() -> None:
        for f in todo:
            f()
    return each


def _bind(text: str) -> tuple[str, int]:
    from feeder_bt.ui import parse_bind
    try:
        return parse_bind(text)
    except argparse.ArgumentTypeError as e:
        raise FeederError(f"--ui: {e}") from None


def _operator_resets(cell: Cell, plan) -> bool:
    """With a fault plan the run stands in for the operator of an e-stop: it waits for the
    release, then resets and restarts the cell (docs/faults.md). Any other FAULT ends it."""
    return plan is not None and cell.fault_reason == "e-stop pressed"


def _operator(cell: Cell) -> None:
    if (cell.state is CellState.FAULT and cell.fault_reason == "e-stop pressed"
            and not cell.estop_pressed()):
        cell.stats.emit(cell.clock.now(), "operator", action="reset and start after e-stop")
        cell.reset()
        cell.start()


def _watch_accounting(cell: Cell) -> Callable[[], bool]:
    """On the simulated cell: every part the world finds lost or duplicated is an event in
    the cell's log, and ends the run (``broken()``); elsewhere nothing to watch."""
    world = cell.hal.truth
    if world is None:
        return lambda: False

    def tell(problem: dict[str, Any]) -> None:
        cell.stats.emit(cell.clock.now(), f"part_{problem['kind']}",
                        **{k: v for k, v in problem.items() if k != "kind"})

    world.listeners.append(tell)
    return lambda: world.broken


def final_speeds(cell: Cell) -> dict[str, float | None]:
    """The speeds the trees followed last (the scenario's, the adjuster's or an operator's)."""
    return cell.speeds()


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
    """Load a scenario on a cell, feed for a while, stop in order, report."""
    run = _Run(opts, _prepare(opts))    # every bad option or file fails before the HAL opens
    run.open_cell()
    run.attach_views()
    try:
        run.take_signals()
        run.serve_operators()
        run.feed()
        run.stop_in_order()
    finally:
        run.close()
    return run.finish_report()


@dataclass
class _Prepared:
    """What a run needs, read and checked before anything opens."""
    scenario: Scenario
    cell_spec: Any
    duration: float | None
    start: bool
    plan: Any = None            # the fault plan
    supply_plan: Any = None
    world: Any = None           # the simulated cell's truth (a world file over the cell)


def _prepare(opts: RunOptions) -> _Prepared:
    """Check the options against each other and read every file the run names; like a bad
    --db, anything wrong fails here, before the HAL opens."""
    if opts.ui and opts.fast:
        raise FeederError("--ui serves operators in real time: drop --fast")
    opcua = bool(opts.plant is not None and opts.plant.opcua)
    if opcua and opts.fast:
        raise FeederError("--opcua serves a plant in real time: drop --fast")
    if opts.fast and opts.plant is not None and opts.plant.part_server \
            and not opts.plant.sim_robot:
        raise FeederError("--fast with --no-sim-robot: virtual time would race ahead of an "
                          "outside robot in real time, and every part would expire before "
                          "it could ask; drop --fast")
    # with --ui the run lasts until Ctrl-C unless --duration; the operator starts the cell
    duration = 60.0 if opts.duration is None and not (opts.ui or opcua) else opts.duration
    start = (not opts.ui) if opts.start is None else opts.start
    if opts.report:
        check_output_file(opts.report, "--report")
    scenario, cell_spec = load_scenario(opts.scenario, opts.cell, overlay=opts.overlay)
    if opts.ui:
        from feeder_bt.ui.app import check_users
        check_users(opts.users)
    if opcua:
        _check_opcua(opts)
    prep = _Prepared(scenario, cell_spec, duration, start)
    if opts.world:
        from feeder_bt.config.world import load_world
        if opts.hal == "real":
            raise ConfigError("a world file is the simulated cell's truth; a real cell is "
                              "its own", key="world")
        prep.world = load_world(opts.world, cell_spec)
    if opts.faults:
        from feeder_bt.config.files import load_fault_plan
        prep.plan = load_fault_plan(opts.faults)
        if opts.hal != "sim":
            raise ConfigError("fault plans drive the simulated cell; the emulators take "
                              "their faults from tests (feeder_bt.emulators.faults)",
                              key="faults")
    if opts.supply:
        from feeder_bt.config.supply import check_against_scenario, load_supply_plan
        from feeder_bt.sim.supply import with_start
        prep.supply_plan = load_supply_plan(opts.supply)
        if opts.hal != "sim":
            raise ConfigError("supply plans drive the simulated cell; on an emulated or "
                              "real cell the plant brings the parts", key="supply")
        check_against_scenario(prep.supply_plan, list(scenario.parts))
        prep.scenario = with_start(scenario, prep.supply_plan)
    return prep


class _Run:
    """One run of the main job, step by step (``run_job`` names the steps)."""

    def __init__(self, opts: RunOptions, prep: _Prepared) -> None:
        self.opts, self.prep = opts, prep
        self.log = EventLog(opts.db) if opts.db else None   # a bad --db fails here too
        self.injector = self.supply = self.trace = self.show = None
        self.ui = self.plant = None
        self.every: Callable[[], None] | None = None
        self.t_stop: float | None = None    # set when feeding ends: the feed time stops
        self.interrupted = False
        self._old_signals: dict = {}
        self.request = _StopRequest()

    # ---------------------------------------------------------------- steps
    def open_cell(self) -> None:
        """The HAL (with the simulated cell's fault and supply plans), the cell, and what
        watches it: the world's accounting, the trees' history, the event log."""
        opts, prep = self.opts, self.prep
        self.hal, clock = make_hal(opts.hal, prep.scenario, prep.cell_spec, opts.seed,
                                    world=prep.world)
        if prep.plan is not None:
            from feeder_bt.sim.faults import inject_faults
            self.injector = inject_faults(self.hal, prep.plan,  # type: ignore[arg-type]
                                          drivers=prep.cell_spec)
        if prep.supply_plan is not None:
            from feeder_bt.sim.supply import apply_supply
            self.supply = apply_supply(self.hal, prep.supply_plan)
        self.clock = clock if isinstance(clock, SimClock) else RealClock()
        self.cell = Cell(prep.cell_spec, self.hal, self.clock)
        self.broken = _watch_accounting(self.cell)
        if self.log or opts.ui:     # the trees' history, for `feeder replay` and the timeline
            from feeder_bt.records.treelog import TreeTrace
            self.trace = TreeTrace(self.cell, live=bool(opts.ui), logged=bool(self.log))
        if self.log:
            _start_log(self.log, opts, prep.scenario, self.cell)
            if self.trace is not None:
                self.log.add_writer(self.trace)

    def attach_views(self) -> None:
        """The ticker, the feed-time span, the progress bar or live view, and what runs
        after each tick."""
        opts = self.opts
        self.ticker = Ticker(self.cell, fast=opts.fast, skip_idle=opts.skip_idle)
        self.t_start = self.clock.now()
        self.feed_span = (_FeedSpan(self.cell)
                          if opts.ui or (opts.plant and opts.plant.opcua) else None)
        if opts.fast:
            self.show = Progress(self.cell, self.prep.duration or 0.0,
                                 feed_seconds=self.feed_seconds)
        elif opts.view != "none":
            self.show = LiveView(self.cell, fmt=opts.view, feed_seconds=self.feed_seconds)
        self.every = _chain(self.trace.after_tick if self.trace else None,
                            self.show.update if self.show else None)
        if self.log:    # after each tick: the view, then the log's batch (cheap when not due)
            self.every = _chain(self.every, self.log.periodic_flush)
        self.wall0 = time.monotonic()

    def take_signals(self) -> None:
        """Ctrl-C and SIGTERM ask for an orderly stop. Only the main thread may take signals
        (a Dask worker runs `feeder tune`'s jobs in one of its threads: there the worker,
        not the run, answers Ctrl-C)."""
        if threading.current_thread() is threading.main_thread():
            self._old_signals = {sig: signal.signal(sig, self.request)
                                 for sig in (signal.SIGINT, signal.SIGTERM)}

    def serve_operators(self) -> None:
        """Load the scenario; open the operator UI and the plant adapters asked for."""
        opts, cell = self.opts, self.cell
        cell.load(self.prep.scenario)
        if opts.ui:             # commands run and snapshots are taken in the tick thread
            from feeder_bt.ui.app import OperatorUi
            self.ui = OperatorUi(cell, opts.scenario, opts.cell or self.prep.scenario.cell_path,
                                 *_bind(opts.ui), users_path=opts.users, t0=self.t_start,
                                 trace=self.trace)
            url = self.ui.start()
            print(f"operator UI: {url}", file=sys.stderr, flush=True)
            if isinstance(self.show, LiveView):
                self.show.note = f"operator UI: {url}"
            self.every = _chain(self.every, self.ui.pump)
        self.plant = _open_plant(opts, cell, self.prep.scenario)
        if self.plant is not None:
            self.every = _chain(self.every, self.plant.pump)

    def feed(self) -> None:
        """Start (unless an operator will) and tick until the duration, a stop request, the
        end of the world's accounting or a FAULT nobody resets."""
        cell, plan, request = self.cell, self.prep.plan, self.request
        if self.prep.start:
            cell.start()
        operated = bool(self.ui) or (self.plant is not None and self.plant.opcua is not None)
        if operated:
            def stop() -> bool:
                return request.requested or self.broken()
        else:
            def stop() -> bool:
                return (request.requested or self.broken() or cell.state is CellState.STOPPED
                        or (cell.state is CellState.FAULT and not _operator_resets(cell, plan)))
        duration = self.prep.duration
        try:
            self.ticker.run(until=None if duration is None else self.t_start + duration,
                            stop=stop,
                            every=_chain(self.every, (lambda: _operator(cell)) if plan else None))
        except KeyboardInterrupt:
            pass
        self.interrupted = request.requested
        self.t_stop = self.clock.now()

    def stop_in_order(self) -> None:
        """Stop the cell and tick its clean-up (operators see it but can no longer
        command); on the simulated clock no need to watch it in real time."""
        ui, plant, cell = self.ui, self.plant, self.cell
        if ui:
            ui.closing()
        if plant is not None:
            plant.closing()
        cell.stop()
        if isinstance(self.clock, SimClock):
            self.ticker.fast, self.ticker.skip_idle = True, self.opts.skip_idle
        self.ticker.run(until=self.clock.now() + STOP_GRACE_S,
                        stop=lambda: cell.state in (CellState.STOPPED, CellState.FAULT),
                        every=_chain(self.trace.after_tick if self.trace else None,
                                     ui.pump if ui else None, plant.pump if plant else None))
        if self.show:
            self.show.update(force=True)

    def close(self) -> None:
        """Everything back as it was, even after an error: the terminal, the signals, the
        servers, the HAL; the event log flushed (nothing buffered is lost)."""
        if self.show:
            self.show.close()
        for sig, handler in self._old_signals.items():
            signal.signal(sig, handler)
        if self.ui:
            self.ui.close()
        if self.plant is not None:
            self.plant.close()
        self.hal.close()
        if self.log:
            self.log.flush()

    def finish_report(self) -> dict[str, Any]:
        """The run report (``RunReport``), written where asked and closed into the event log;
        its JSON is returned, as written."""
        opts = self.opts
        report = build_report(self.cell, self.ticker, seed=opts.seed, hal=opts.hal,
                              sim_seconds=self.clock.now() - self.t_start,
                              feed_seconds=self.feed_seconds(),
                              wall_seconds=time.monotonic() - self.wall0,
                              interrupted=self.interrupted,
                              inflow=self.supply.inflow() if self.supply is not None else None,
                              inflow_by_type=(self.supply.inflow_by_type()
                                              if self.supply is not None else None))
        report.speeds = final_speeds(self.cell)
        if self.injector is not None:
            report.injected = dict(self.injector.injected)
            report.unseen = dict(self.injector.unseen)     # injected, met by nobody
            report.watchdog_stops = self.injector.watchdog_stops   # #WDOG outages
            report.fault_plan = str(opts.faults)
        links = getattr(self.hal, "links", None)      # the drivers' links (not the sim's)
        if links is not None:
            seen = links()
            report.reconnects = seen["reconnects"]
            if "watchdog_stops" in seen:
                report.watchdog_stops = seen["watchdog_stops"]
        if self.supply is not None:
            report.supply = self.supply.report()
        if self.ui:
            report.operator = self.ui.report()
        if self.plant is not None:
            report.update(self.plant.report())
        data = report.to_json()
        if self.log:                    # the run's row first: a report path that fails
            self.log.finish(data)       # at the end must not leave it unfinished
            self.log.close()
        if opts.report:
            write_report(data, opts.report, fallback_dir=Path(DEFAULT_DB).parent)
        return data

    # ---------------------------------------------------------------- helpers
    def feed_seconds(self) -> float:
        """The feeding time the report counts, so far: the view's parts/min is the report's."""
        t = self.clock.now() if self.t_stop is None else self.t_stop
        return self.feed_span.seconds(t) if self.feed_span else t - self.t_start
