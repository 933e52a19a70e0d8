"""The twin's round trip: plants unknown to the fit, a log of each, a twin, predictions.

A *plant* is a world file whose figures are moved from the cell file's within what the
simulator's documentation says is unknown about them (docs/simulator.md): the hopper's
release ±30 %, the return transit ±20 %, the clumping scale ×0.5–2, the arm's joint speeds
±15 % each, the grip curve's width ×0.5–2. The fit sees only the plant's event log; the
twin's predictions at other settings are set against the plant's own mean over seeds, and
beside them the uncalibrated defaults' (the cell file's figures).
"""

from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from feeder_bt.core.model import CellSpec
from feeder_bt.robot.scara import arm_figures, world_arm
from feeder_bt.tuning.twin import world_yaml

#: (flat world key, how it is drawn: "uniform" ± fraction or "log" factor range)
PLANT_RANGES: tuple[tuple[str, str, float, float], ...] = (
    ("hopper.release_per_mm", "uniform", 0.7, 1.3),
    ("return_transit_s", "uniform", 0.8, 1.2),
    ("sim.clump_cover_scale", "log", 0.5, 2.0),
    ("sim.arm_j1_deg_s", "uniform", 0.85, 1.15),
    ("sim.arm_j2_deg_s", "uniform", 0.85, 1.15),
    ("sim.grip_width_mm", "log", 0.5, 2.0),
)


#: a plate cell's plants (docs/plate-feeders.md, "Physics": every plate figure is an
#: assumption): the dispense count ×0.6–1.5, the flip's re-draw probability ×0.75–1.15
#: (0.6–0.92), its scatter ×0.5–2, the feed distance ±30 %, the repetition's time
#: ×0.75–1.3 and the settling ×0.7–1.4, the arm's joint speeds ±15 % each
PLATE_RANGES: tuple[tuple[str, str, float, float], ...] = (
    ("plate.dispense_per_rep", "uniform", 0.6, 1.5),
    ("plate.flip_prob", "uniform", 0.75, 1.15),
    ("plate.flip_scatter_mm", "log", 0.5, 2.0),
    ("plate.feed_mm_per_rep", "uniform", 0.7, 1.3),
    ("plate.rep_s", "uniform", 0.75, 1.3),
    ("plate.settle_s", "uniform", 0.7, 1.4),
    ("sim.arm_j1_deg_s", "uniform", 0.85, 1.15),
    ("sim.arm_j2_deg_s", "uniform", 0.85, 1.15),
)


def nominal_figures(cell: CellSpec) -> dict[str, float]:
    """The cell file's value of every figure a plant moves."""
    arm = arm_figures(world_arm(cell.robot).scara)
    if cell.presentation == "plate":
        p = cell.plate
        return {"plate.dispense_per_rep": p.dispense_per_rep, "plate.flip_prob": p.flip_prob,
                "plate.flip_scatter_mm": p.flip_scatter_mm,
                "plate.feed_mm_per_rep": p.feed_mm_per_rep, "plate.rep_s": p.rep_s,
                "plate.settle_s": p.settle_s, "sim.arm_j1_deg_s": arm["arm_j1_deg_s"],
                "sim.arm_j2_deg_s": arm["arm_j2_deg_s"]}
    return {"hopper.release_per_mm": cell.hopper.release_per_mm,
            "return_transit_s": cell.return_transit_s,
            "sim.clump_cover_scale": cell.sim.clump_cover_scale,
            "sim.arm_j1_deg_s": arm["arm_j1_deg_s"], "sim.arm_j2_deg_s": arm["arm_j2_deg_s"],
            "sim.grip_width_mm": cell.sim.grip_width_mm}


def draw_plants(cell: CellSpec, n: int, seed: int) -> list[dict[str, float]]:
    """``n`` plants' figures, drawn from ``PLANT_RANGES`` (a plate cell's:
    ``PLATE_RANGES``) with a fixed seed."""
    rng = np.random.default_rng(seed)
    nominal = nominal_figures(cell)
    ranges = PLATE_RANGES if cell.presentation == "plate" else PLANT_RANGES
    plants = []
    for _ in range(n):
        fig = {}
        for key, how, lo, hi in ranges:
            f = (rng.uniform(lo, hi) if how == "uniform"
                 else math.exp(rng.uniform(math.log(lo), math.log(hi))))
            fig[key] = nominal[key] * f
        plants.append(fig)
    return plants


@dataclass
class Setting:
    """A way of running the cell: a scenario and an overlay of it (None: as it is)."""

    name: str
    scenario: str
    overlay: dict[str, Any] | None = None


@dataclass
class Runner:
    """Runs settings on worlds and gives parts/min; files go to a scratch folder."""

    duration: float
    tmp: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="twin-")))
    _n: int = 0

    def _file(self, data: dict[str, Any]) -> str:
        self._n += 1
        p = self.tmp / f"f{self._n}.yaml"
        p.write_text(yaml.safe_dump(data, sort_keys=False))
        return str(p)

    def world(self, figures: dict[str, float] | None) -> str | None:
        return None if figures is None else self._file(world_yaml(figures))

    def ppm(self, setting: Setting, world: str | None, seeds: tuple[int, ...],
            db: str | None = None) -> float:
        """Mean parts/min over ``seeds`` of ``setting`` on ``world`` (None: the cell)."""
        from feeder_bt.app.run import RunOptions, run_job
        overlay = self._file(setting.overlay) if setting.overlay else None
        out = []
        for seed in seeds:
            r = run_job(RunOptions(scenario=setting.scenario, duration=self.duration,
                                   fast=True, seed=seed, view="none", db=db,
                                   overlay=overlay, world=world))
            out.append(float(r["parts_per_minute"]))
        return float(np.mean(out))
