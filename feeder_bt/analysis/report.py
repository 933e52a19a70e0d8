"""The run report: the JSON contract for CI, benchmarks and users comparing settings."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from feeder_bt.analysis.robot_bounds import Pricing, mean_bound, selection_bound
from feeder_bt.analysis.run_report import RunReport, check_written
from feeder_bt.control.cell import Cell
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.core.outputs import write_or_fallback
from feeder_bt.core.vocabulary import split
from feeder_bt.policy.kits import KitTracker, kits_report, steady_kits
from feeder_bt.policy.supply_bound import (
    ceiling,
    inflow_bound_parts,
    supply_bound_ppm,
    transport_lag_s,
)
from feeder_bt.robot.model import RobotModel


def _pct(values: list[float], q: float) -> float:
    return round(float(np.percentile(values, q)), 3) if values else 0.0


def pick_window(cell_spec: CellSpec, scenario: Scenario) -> tuple[float, float, float, float]:
    """Where a part's centre can be when picked: along the belt up to ``too_far`` (or the
    belt's end), across it inside the side rails. (x_lo, x_hi, y_lo, y_hi) in mm."""
    from feeder_bt.sim.world import EDGE_MARGIN_MM

    belt = cell_spec.conveyors["horizontal"]
    x_hi = min(scenario.retrieve.too_far_mm, belt.length_mm)
    return 0.0, x_hi, EDGE_MARGIN_MM, belt.width_mm - EDGE_MARGIN_MM


def robot_bound(cell_spec: CellSpec, scenario: Scenario,
                model: RobotModel | None = None) -> tuple[float, float]:
    """(cycle s, parts/min): the shortest pick-and-place cycle the robot model allows at the
    scenario's robot speed — pick at the best point of the pick window, place, back — and
    the throughput no feeder setting can beat with this robot. Over part types, the best.
    ``model``: another model of the robot than the cell's (the one fitted online)."""
    model = model or RobotModel(cell_spec.robot)
    window = pick_window(cell_spec, scenario)
    r = scenario.retrieve
    cycles = [model.shortest_cycle((spec.place.x, spec.place.y), window, r.robot_speed_pct,
                                   r.tracking) for spec in scenario.parts.values()]
    valid = [c for c in cycles if c is not None and c > 0]
    if not valid:
        return 0.0, 0.0
    cycle = min(valid)
    return cycle, 60.0 / cycle


Inflow = tuple[int, list[tuple[float, int]]]      # parts at the start, (s, parts) arrivals


def bounds(located_in_reach: int, robot_ppm: float, retrieved: int, feed_seconds: float,
           inflow: Inflow | None = None, span_s: float | None = None,
           selection_ppm: float | None = None, lag_s: float = 0.0) -> dict[str, Any]:
    """The supply bound (``feeder_bt.policy.supply_bound``) beside the robot's, and the inflow
    bound when parts enter only by totes; the lowest is the ceiling, and parts/min as a %
    of it. The inflow bound counts parts over the run's whole ``span_s``, each arrival
    ``lag_s`` late (the ride to the robot), and is put per minute of feeding, like
    parts/min. ``selection_ppm``: nearest-first over the run's parts (robot_bounds.py), a
    yardstick and never the ceiling: parts/min as a ratio to it, ``of_selection``."""
    supply = supply_bound_ppm(located_in_reach, feed_seconds)
    out: dict[str, Any] = {"supply_bound_ppm": round(supply, 3)}
    inflow_ppm = None
    if inflow is not None and feed_seconds > 0:
        parts = inflow_bound_parts(*inflow, robot_ppm, span_s or feed_seconds, lag_s)
        inflow_ppm = parts * 60.0 / feed_seconds
        out["inflow_bound_ppm"] = round(inflow_ppm, 3)
        out["inflow_lag_s"] = round(lag_s, 3)
    which, ceil = ceiling(robot_ppm, supply, inflow_ppm)
    ppm = retrieved * 60.0 / feed_seconds if feed_seconds > 0 else 0.0
    if selection_ppm:
        out["of_selection"] = round(ppm / selection_ppm, 3)
    return {**out, "ceiling": which, "ceiling_ppm": round(ceil, 3),
            "of_ceiling_pct": round(100.0 * ppm / ceil, 1) if ceil > 0 else None}


def world_robot_bounds(cell_spec: CellSpec, scenario: Scenario, world: Any,
                       feed_seconds: float, sim_seconds: float) -> dict[str, Any]:
    """The selection-aware robot yardsticks over the simulated world's record of the run
    (``feeder_bt.analysis.robot_bounds``), with the world's own arm: the mean cycle over where the
    robot picked, and nearest-first over the parts that passed."""
    since = _record_since(world, sim_seconds)
    if since is not None:
        return {"robot_bounds_since_s": since}
    pricing = Pricing.of(world.robot_model, cell_spec, scenario)
    log = world.passlog
    mean = mean_bound(pricing, log.picks)
    out = {"robot_bound_mean_ppm": round(mean[1], 3) if mean else None,
           "robot_bound_mean_cycle_s": round(mean[0], 4) if mean else None}
    if cell_spec.presentation == "plate":   # nothing passes a plate: no nearest-first replay
        return out
    placed = selection_bound(pricing, log, tuple(cell_spec.robot.safe_mm), world.clock.now(),
                             placed_leave=world.ship_placed)
    sel = placed * 60.0 / feed_seconds if feed_seconds > 0 else 0.0
    return {**out, "robot_bound_selection_ppm": round(sel, 3),
            "robot_bound_selection_parts": placed}


def world_kit_selection(cell_spec: CellSpec, scenario: Scenario, world: Any, kit: KitTracker,
                        sim_seconds: float) -> int | None:
    """Kits a nearest-first robot taking only the types the kit wants completes from the
    run's passes (``robot_bounds.selection_bound``); None where the replay cannot run."""
    if _record_since(world, sim_seconds) is not None or cell_spec.presentation == "plate":
        return None
    replay = KitTracker(kit.counts, kit.order, kit.open_kits)
    selection_bound(Pricing.of(world.robot_model, cell_spec, scenario), world.passlog,
                    tuple(cell_spec.robot.safe_mm), world.clock.now(), replay,
                    placed_leave=world.ship_placed)
    return replay.completed


def _record_since(world: Any, sim_seconds: float) -> float | None:
    """None if the world's record covers the whole run; else from when it does: a
    changeover (the operator loaded another scenario) began a new world, whose record
    would not bound the run."""
    start = world.passlog.belt_t[0] - (world.clock.now() - sim_seconds)
    return round(start, 3) if start > 1e-6 else None


def build_report(cell: Cell, ticker: Ticker, *, seed: int, hal: str, sim_seconds: float,
                 feed_seconds: float, wall_seconds: float, interrupted: bool = False,
                 inflow: Inflow | None = None,
                 inflow_by_type: dict[str, Inflow] | None = None) -> RunReport:
    """The run's report from the cell's statistics, its robot fit and, on the simulated
    cell, the world's truth (``Hal.truth``)."""
    s = cell.stats
    retrieved = {name: s.retrieved.get(name, 0) for name in (cell.scenario.parts if cell.scenario
                                                            else {})}
    total = sum(retrieved.values())
    world = cell.hal.truth
    if world is not None:
        world.audit()                     # the final check, part by part
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
        "duplicated": world.duplicated() if world else None,
        "misplaced": dict(world.misplaced_by_type) if world else None,
        "dropped": s.counts["dropped"],
    }
    if world is not None:                 # why the simulated grips missed
        parts["grip_misses"] = {k: world.counts[k] for k in (
            "grip_empty", "grip_refused", "grip_slipped", "grip_on_hole", "grip_on_neighbour")}
    if world is not None:                 # every part that entered the cell, and left it
        parts["supplied"] = world.total
        parts["shipped"] = world.counts["shipped"]
        # wear: passes a plant pays for, and parts worn past max_passes
        parts["scrapped"] = world.counts["scrapped"]
        parts["recirculated_per_placed"] = (round(world.counts["recirculated"] / total, 3)
                                            if total else None)
    if world is not None and world.problems:
        parts["accounting"] = world.problems[:50]      # each part named, id and place
    if world is not None:
        mismatch = outcome_mismatch(dict(world.placed_by_type), retrieved)
        if mismatch:
            parts["outcomes"] = mismatch
    # the robot bounds priced with the arm as it really moves: the simulated world's SCARA
    # (feeder_bt.robot.scara), or on a real cell the cell's description
    arm = world.robot_model if world is not None else None
    bound_cycle, bound_ppm = (robot_bound(cell.cell, cell.scenario, arm) if cell.scenario
                              else (0.0, 0.0))
    robot_bounds = (world_robot_bounds(cell.cell, cell.scenario, world, feed_seconds,
                                       sim_seconds)
                    if world is not None and cell.scenario else {})
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
        # the corner case: the shortest cycle anywhere in the pick window
        "robot_bound_ppm": round(bound_ppm, 3),
        "robot_bound_cycle_s": round(bound_cycle, 4),
        "robot_bound_kind": "corner",
        **robot_bounds,
        **bounds(s.counts["located_in_reach"], bound_ppm, total, feed_seconds, inflow,
                 sim_seconds, robot_bounds.get("robot_bound_selection_ppm"),
                 transport_lag_s(cell.cell)),
        "parts": parts,
        # one vocabulary (vocabulary.py): device faults apart from the misses the trees retry
        "faults": split(s.faults)[0],
        "misses": split(s.faults)[1],
        "recoveries": dict(s.recoveries),
        "retried": dict(s.retried),
        "encoder_drift": dict(s.drift),
        "tick": ticker.stats.summary(),
        "vision": {"frames": s.counts["frames"], "p50_ms": _pct(s.vision_ms, 50),
                   "p99_ms": _pct(s.vision_ms, 99), "no_match": _no_match(cell),
                   "gripper_blocked": s.counts["gripper_blocked"]},
    }
    if s.kit is not None:                 # kits (thesis 8.2.1.5): how many, how fast, bounds
        kit_sel = (world_kit_selection(cell.cell, cell.scenario, world, s.kit, sim_seconds)
                   if world is not None and cell.scenario else None)
        report["kits"] = kits_report(s.kit, s.in_reach_by_type, feed_seconds, bound_ppm,
                                     inflow_by_type, sim_seconds, transport_lag_s(cell.cell),
                                     kit_sel)
    if cell.cell.presentation == "plate":   # the plate's actions
        report["plate"] = {k[len("plate_"):]: v for k, v in sorted(s.counts.items())
                           if k.startswith("plate_")}
    counts = getattr(getattr(getattr(cell.hal, "camera", None), "source", None), "counts",
                     None)
    if callable(counts):                  # a camera counting its frames (hal/camera/pylon.py)
        report["camera"] = counts()
    fit = cell.ctx.extras.get("robot_fit") if cell.ctx is not None else None
    if fit is not None:                   # the model the pick policies learnt (robot_fit.py)
        report["robot_model"] = fit.summary()
        # the arm's share of feeding spent on picks and places that ended (a missed grip's
        # time is not in it): near 100 %, the robot is what limits the cell
        report["robot_busy_pct"] = (round(100.0 * fit.busy_s / feed_seconds, 1)
                                    if feed_seconds > 0 else None)
        report["robot_time"] = fit.time_split(feed_seconds, s.started_at)
        if "kits" in report and total > 0:
            report["kits"].update(steady_kits(report["kits"]["kit"], total, feed_seconds,
                                              fit.busy_s - fit.waited_s))
        report["robot_model"]["fitted"]["robot_bound_ppm"] = round(
            robot_bound(cell.cell, cell.scenario, fit.model)[1], 3)
        if world is not None:             # the simulated arm's truth, for comparison
            # the world's own (a world file may set it apart from the cell file)
            report["robot_model"]["sim_speed_factor"] = world.cell.robot.sim_speed_factor
    if world is not None:
        report["world"] = {"census": world.census(), "released": world.counts["released"],
                           "landed": world.counts["landed"],
                           "landed_touching": world.counts["landed_touching"],
                           # the simulator's imperfections at work (docs/simulator.md)
                           "landed_clumped": world.counts["landed_clumped"],
                           "grip_slipped": world.counts["grip_slipped"],
                           # the arm's waits at the reach for parts it gripped (robot_time)
                           "pick_waited_s": round(world.pick_waited_s, 2),
                           # parts that slid on the belt (a hard speed change), and how far
                           "slips": world.counts["slips"],
                           "slid_mm": round(world.slid_mm, 1),
                           "placed": dict(world.placed_by_type),
                           # commands a belt ran slower than asked (0: the HAL refuses them)
                           "axis_clamped": {"horizontal": world.horizontal.clamped,
                                            "incline": world.incline.clamped}}
    return RunReport.from_json(report)


def _no_match(cell: Cell) -> dict[str, Any] | None:
    """The vision watch's summary (``feeder_bt.vision.watch``): frames that fit no class."""
    watch = cell.ctx.extras.get("recipe_watch") if cell.ctx is not None else None
    return watch.summary() if watch is not None else None


def outcome_mismatch(placed: dict[str, int], counted: dict[str, int]
                     ) -> dict[str, dict[str, int]]:
    """Every placement the world saw is one the cell counted, and the reverse: what does
    not pair off, by type (``world_only``: placed, not counted, as when a PLACED's reply
    was lost; ``cell_only``: counted, never placed). Empty when they agree."""
    kinds = sorted(set(placed) | set(counted))
    world_only = {k: placed.get(k, 0) - counted.get(k, 0) for k in kinds
                  if placed.get(k, 0) > counted.get(k, 0)}
    cell_only = {k: counted.get(k, 0) - placed.get(k, 0) for k in kinds
                 if counted.get(k, 0) > placed.get(k, 0)}
    return {"world_only": world_only, "cell_only": cell_only} if world_only or cell_only \
        else {}


def write_report(report: RunReport | dict[str, Any], path: str | Path,
                 fallback_dir: str | Path | None = None) -> Path:
    """The report's JSON to ``path`` (checked against its schema where the tests ask);
    with ``fallback_dir``, a report that cannot be written there goes to a file in it,
    named on standard error (``core.outputs.write_or_fallback``). Returns where it went."""
    data = report.to_json() if isinstance(report, RunReport) else report
    check_written(data)
    text = json.dumps(data, indent=2) + "\n"
    if fallback_dir is None:
        Path(path).write_text(text)
        return Path(path)
    return write_or_fallback(path, text, "run report", fallback_dir)
