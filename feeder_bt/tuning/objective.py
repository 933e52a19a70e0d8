"""One evaluation of ``feeder tune``: a scenario with an overlay, one seed, virtual time.

It runs in a worker (a local process or a Dask worker), so it takes and returns plain
data: the worker writes the overlay to a temporary file and runs the scenario exactly as
``feeder run SCENARIO --overlay FILE --fast --seed S`` would, so that the overlay
``feeder tune --out`` writes reproduces the trial. Scenario and cell paths must be
readable by the worker (a Dask cluster needs the project's files where its workers run).
"""

from __future__ import annotations

import contextlib
import dataclasses
import io
import tempfile
import threading
from pathlib import Path
from typing import Any

from feeder_bt.core.errors import FeederError

#: runs in one process (a Dask worker's threads) take turns: each cell has its own
#: blackboard and ticker news, but the run's progress goes to ``sys.stderr``, which
#: ``redirect_stderr`` swaps for the whole process (two at once would leave a run's
#: StringIO as the worker's stderr)
_ONE_RUN_AT_A_TIME = threading.Lock()


@dataclasses.dataclass(frozen=True)
class Job:
    """What one evaluation needs; plain data, so that it pickles to any worker."""

    scenario: str
    overlay: dict[str, Any]
    seed: int
    duration: float
    cell: str | None = None
    supply: str | None = None
    world: str | None = None        # the simulated cell's truth (a twin: feeder twin fit)


def evaluate(job: Job) -> dict[str, Any]:
    """Run ``job`` and return its parts/min and the figures the tuner keeps per trial.

    A scenario the loader refuses, or a run that faults, is returned as ``error`` (the
    tuner records the trial as failed with that line) rather than raised, so one bad point
    never stops a search.
    """
    from feeder_bt.app.run import RunOptions, run_job
    from feeder_bt.config.overlay import write_overlay

    extra: dict[str, Any] = {}
    if job.supply:
        if "supply" not in {f.name for f in dataclasses.fields(RunOptions)}:
            return {"error": "--supply needs a feeder_bt whose `feeder run` takes supply plans"}
        extra["supply"] = job.supply
    if job.world:
        extra["world"] = job.world
    with tempfile.TemporaryDirectory(prefix="feeder-tune-") as d:
        path = Path(d) / "overlay.yaml"
        write_overlay(path, job.overlay)
        try:
            with _ONE_RUN_AT_A_TIME, contextlib.redirect_stderr(io.StringIO()):
                report = run_job(RunOptions(scenario=job.scenario, cell=job.cell,
                                            duration=job.duration, fast=True, seed=job.seed,
                                            view="none", db=None, overlay=str(path),
                                            **extra))
        except FeederError as e:
            return {"error": str(e).replace(str(path), "overlay")}
    if report.get("interrupted"):               # Ctrl-C reached the worker: not a value
        return {"interrupted": True, "error": "interrupted", "seed": job.seed}  # INTERRUPTED
    parts = report["parts"]
    out = {"ppm": float(report["parts_per_minute"]), "seed": job.seed,
           "robot_bound_ppm": report.get("robot_bound_ppm"),
           "robot_bound_selection_ppm": report.get("robot_bound_selection_ppm"),
           "inflow_bound_ppm": report.get("inflow_bound_ppm"),
           "robot_busy_pct": report.get("robot_busy_pct"),
           "robot_time": report.get("robot_time"),
           "ceiling_ppm": report.get("ceiling_ppm"),
           "lost": parts.get("lost") or 0, "missed": parts.get("missed") or 0,
           "recirc_per_placed": parts.get("recirculated_per_placed"),
           "fault": report.get("fault")}
    kits = report.get("kits")
    if kits:                    # a kit scenario's objective (search.objective_unit)
        out["kpm"] = float(kits["per_minute"])
        out["kit_ceiling_kpm"] = kits.get("ceiling_kpm")
        out["kit_bounds_kpm"] = {k[:-len("_bound_kpm")]: v for k, v in kits.items()
                                 if k.endswith("_bound_kpm")}
        out["kits"] = kits.get("completed")
    if report.get("fault"):
        out["error"] = f"the run faulted: {report['fault']}"
    return out
