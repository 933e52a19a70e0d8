"""The public API: what code outside feeder_bt imports, and the promise that these names stay.

Everything else in ``feeder_bt`` is internal and may move between releases; these names
are kept (a rename keeps the old name here for a release, with a warning). Import them from
here, never from the module that defines them::

    from feeder_bt.api import Locator, LocateResult, pose_outline

Who needs what:

- **a leaf class** a scenario names in place of ours (``locate.leaf``, ``retrieve.leaf``;
  docs/adding-a-part.md): subclass ``Recognise`` or ``Pick`` (``LEAF_BASES`` says which key
  takes which); a leaf gets the cell's context ``Ctx`` (HAL, clock, scenario, queue,
  statistics), starts ``Job``s and returns a py_trees ``Status``;
- **a locator plug-in** (``vision.leaf``): subclass ``Locator``; ``locate`` returns a
  ``LocateResult`` of ``Detection``s; ``pose_outline`` draws a part's outline in a pose and
  ``Calibration`` maps pixels to belt millimetres;
- **an adjuster** (``adjust.leaf``): subclass ``Adjuster``; it reads ``AdjustInputs`` and
  returns ``Speeds``;
- **a HAL implementation** (a new conveyor, robot, camera or feeder driver): implement the
  protocols ``Conveyor``, ``Robot``, ``RobotPosition``, ``Camera``, ``DigitalIO``,
  ``PlateFeeder`` and put them in a ``Hal``; anything that takes time returns a ``Job``
  (``DoneJob`` for what is already done) and fails with the typed errors below;
- **a report reader**: ``RunReport.from_json(json.load(f))`` for a ``--report`` file
  (``report_schema()`` is what ``feeder schema report`` prints); ``open_runs`` and
  ``run_summary`` for the runs database (``--db``);
- **a robot program in Python** pulling parts from the part server (docs/part-server.md):
  ``PartClient`` (its ``Offer``s, ``PartServerError``);
- **the files**: ``load_scenario``, ``load_cell``, ``check_files``.
"""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

from py_trees.common import Status

from feeder_bt.analysis.run_report import ABSENT, ReportError, RunReport, report_schema
from feeder_bt.behaviours.base import Ctx, JobLeaf, Stats
from feeder_bt.behaviours.locate import Recognise
from feeder_bt.behaviours.retrieve import Pick
from feeder_bt.config import CellSpec, Scenario, check_files, load_cell, load_scenario
from feeder_bt.core.errors import (
    CommsLost,
    ConfigError,
    ConveyorFault,
    EnvelopeError,
    FeederError,
    GrabFailed,
    HalError,
    MissedGrab,
    PlateFault,
    ServoTimeout,
)
from feeder_bt.core.geometry import pose_outline
from feeder_bt.core.jobs import DoneJob, Job, JobState
from feeder_bt.core.part_protocol import Offer
from feeder_bt.core.parts import Part
from feeder_bt.hal.interfaces import (
    Camera,
    Conveyor,
    DigitalIO,
    Frame,
    Hal,
    Held,
    IoChange,
    PickResult,
    PickTarget,
    PlateFeeder,
    PlateStatus,
    Pose,
    Robot,
    RobotPosition,
)
from feeder_bt.plant.client import PartClient, PartServerError
from feeder_bt.policy.adjusters import Adjuster, AdjustInputs, Speeds
from feeder_bt.records.runs_db import run_ids
from feeder_bt.records.runs_db import summary as _summary
from feeder_bt.trees.leaves import LEAF_BASES
from feeder_bt.vision.locator import Detection, LocateResult, Locator
from feeder_bt.vision.pixels import Calibration


def open_runs(path: str | Path) -> sqlite3.Connection:
    """The runs database a run wrote (``feeder run --db``), opened read-only."""
    return sqlite3.connect(f"file:{Path(path)}?mode=ro", uri=True)


def run_summary(conn: sqlite3.Connection, run: int | None = None) -> dict[str, Any]:
    """One run's summary as ``feeder report`` shows it (the last run without ``run``)."""
    ids = run_ids(conn, run, last=run is None)
    return _summary(conn, ids[-1])


__all__ = [
    # leaf classes
    "Ctx", "JobLeaf", "LEAF_BASES", "Pick", "Recognise", "Stats", "Status",
    # locator plug-ins
    "Calibration", "Detection", "LocateResult", "Locator", "pose_outline",
    # adjusters
    "AdjustInputs", "Adjuster", "Speeds",
    # HAL implementations
    "Camera", "Conveyor", "DigitalIO", "DoneJob", "Frame", "Hal", "Held", "IoChange", "Job",
    "JobState", "Part", "PickResult", "PickTarget", "PlateFeeder", "PlateStatus", "Pose",
    "Robot", "RobotPosition",
    # errors
    "CommsLost", "ConfigError", "ConveyorFault", "EnvelopeError", "FeederError", "GrabFailed",
    "HalError", "MissedGrab", "PlateFault", "ServoTimeout",
    # reports
    "ABSENT", "ReportError", "RunReport", "open_runs", "report_schema", "run_summary",
    # the part server's reference client
    "Offer", "PartClient", "PartServerError",
    # files
    "CellSpec", "Scenario", "check_files", "load_cell", "load_scenario",
]
