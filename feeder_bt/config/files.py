"""Any YAML file of the project (scenario, cell, fault plan, supply plan), its kind told by
its keys: ``feeder check`` reads every file through here, so that each kind is loaded by
its own module and the loader need not know them all."""

from __future__ import annotations

from pathlib import Path

from feeder_bt.config.faults import FaultPlanSpec, check_fault_plan
from feeder_bt.config.loader import _compose, _Ctx, load_cell, load_scenario
from feeder_bt.config.schema import check_kind, file_kind
from feeder_bt.config.supply import load_supply_plan
from feeder_bt.core.errors import ConfigError


def load_fault_plan(path: str | Path) -> FaultPlanSpec:
    """Load and validate a fault plan for the simulated cell (``docs/faults.md``)."""
    path = Path(path)
    ctx = _Ctx(str(path))
    root = _compose(path, ctx)
    check_kind(root, "faults", path)
    plan = ctx.collect(ctx.dataclass, FaultPlanSpec, root, "", fill={"path": path})
    if plan is not None:
        ctx.collect(check_fault_plan, plan, ctx)
    ctx.raise_problems()
    return plan


LOADERS = {"scenario": load_scenario, "cell": load_cell, "faults": load_fault_plan,
           "supply": load_supply_plan}


def check_file(path: str | Path) -> tuple[str, str | None, list[ConfigError]]:
    """Validate one file of any kind, told by its keys (``schema.file_kind``): (the kind it
    was read as, that kind when its keys told it or None when it was a guess, every
    problem). A scenario is checked with its cell."""
    told = file_kind(path)
    kind = told or "scenario"
    if kind in ("cell", "scenario"):
        from feeder_bt.config.world import check_world, looks_like_world
        # a world file: no name, only world figures (one with only ``hopper:`` ties with
        # a scenario's keys, but a scenario has a name)
        if looks_like_world(path):
            kind = told = "world"
    try:
        (check_world if kind == "world" else LOADERS[kind])(path)
    except ConfigError as e:
        return kind, told, e.problems
    return kind, told, []


def check_files(paths: list[str]) -> list[str]:
    """Validate files of any kind: one line per problem, every problem of every file."""
    return [str(e) for p in paths for e in check_file(p)[2]]

