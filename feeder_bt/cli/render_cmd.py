"""``feeder render``: the frames the simulated camera grabs during a short fast run.

The frames come from a real run of the scenario on the simulated cell (the cell's own grabs,
in order, with its noise, blur and vignetting), so a recipe tuned on them is tuned on what
the locator will see. ``golden.png`` is the cleared, lit belt for golden-image subtraction.
With ``--truth`` each frame gets a JSON of the simulator's ground truth at the trigger:
for the user and the tests only — nothing in the control path reads these files.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import SimClock
from feeder_bt.core.geometry import outer, place_outline
from feeder_bt.core.images import BadInput, write_image
from feeder_bt.core.jobs import Job
from feeder_bt.hal.interfaces import Frame
from feeder_bt.sim.devices import make_sim_hal
from feeder_bt.vision.pixels import Calibration

MAX_RUN_S = 900.0          # virtual seconds to wait for enough frames with parts in them
STOP_GRACE_S = 30.0


@dataclass
class Rendered:
    """What ``render_frames`` produced, for the command and for tests."""

    golden: np.ndarray
    frames: list[np.ndarray] = field(default_factory=list)
    truth: list[dict[str, Any]] = field(default_factory=list)


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("render", help="save the frames the simulated camera sees "
                                             "during a short fast run")
    p.add_argument("scenario", help="scenario YAML")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the PNG files")
    p.add_argument("--frames", type=int, default=8, metavar="N",
                   help="frames to save, each with at least one part in view (default 8)")
    p.add_argument("--seed", type=int, default=1, help="seed of the simulated cell (default 1)")
    p.add_argument("--truth", action="store_true",
                   help="also write frame_NNN.json: the ground truth of the parts in view")
    p.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    p.set_defaults(handler=cmd_render)
    return p


def cmd_render(args: argparse.Namespace) -> int:
    if args.frames < 1:
        raise BadInput(f"--frames must be >= 1, got {args.frames}")
    out = Path(args.out)
    got = render_frames(args.scenario, args.frames, args.seed, args.cell)
    stale = clear_earlier_render(out)
    write_image(out / "golden.png", got.golden)
    for i, (img, truth) in enumerate(zip(got.frames, got.truth, strict=True)):
        write_image(out / f"frame_{i:03d}.png", img)
        if args.truth:
            (out / f"frame_{i:03d}.json").write_text(json.dumps(truth, indent=1) + "\n")
    parts = sum(len(t["parts"]) for t in got.truth)
    note = "" if len(got.frames) == args.frames else \
        f" (only {len(got.frames)} of {args.frames} within {MAX_RUN_S:.0f} s of feeding)"
    print(f"wrote golden.png and {len(got.frames)} frame(s) with {parts} part(s) in view "
          f"to {out}{note}" + (", with truth JSON" if args.truth else "")
          + (f"; removed {stale} file(s) of an earlier render there" if stale else ""))
    return 0


def clear_earlier_render(out: Path) -> int:
    """Remove what an earlier ``feeder render`` wrote to ``out`` (its golden image and its
    frames with their truth), so that a folder holds one render and ``feeder locate
    DIR/frame_*.png`` reads no frame of another scenario; any other file is left alone."""
    if not out.is_dir():
        return 0
    old = [p for p in out.iterdir() if p.is_file() and (
        p.name == "golden.png" or re.fullmatch(r"frame_\d{3,}\.(png|json)", p.name))]
    for p in old:
        try:
            p.unlink()
        except OSError as e:
            raise BadInput(f"{p}: cannot remove the earlier render's file: "
                           f"{e.strerror or e}") from None
    return len(old)


def render_frames(scenario_path: str, n: int, seed: int = 1,
                  cell_path: str | None = None) -> Rendered:
    """Run the scenario on the simulated cell and keep the first ``n`` frames it grabs that
    show at least one part, with the ground truth at each trigger."""
    scenario, cell_spec = load_scenario(scenario_path, cell_path)
    clock = SimClock()
    hal = make_sim_hal(scenario, cell_spec, clock, seed)
    world, camera = hal.world, hal.camera
    cal = Calibration(cell_spec.camera.calibration)
    size = (cell_spec.camera.width_px, cell_spec.camera.height_px)
    got = Rendered(golden=camera.renderer.golden(np.random.default_rng([seed, 0])))
    grab = camera.grab

    def grab_and_keep() -> Job:
        job = grab()
        truth = _truth(world, cal, size)      # at the trigger, before anything moves on
        if truth:
            def keep(j: Job) -> None:
                if j.ok and len(got.frames) < n:
                    frame: Frame = j.result
                    got.frames.append(frame.image.copy())
                    got.truth.append({"frame": len(got.truth), "t": round(frame.t, 6),
                                      "latch": frame.latch, "parts": truth})
            job.add_done_callback(keep)
        return job

    camera.grab = grab_and_keep
    cell = Cell(cell_spec, hal, clock)
    ticker = Ticker(cell, fast=True)
    try:
        cell.load(scenario)
        cell.start()
        t0 = clock.now()
        ticker.run(until=t0 + MAX_RUN_S, stop=lambda: len(got.frames) >= n
                   or cell.state in (CellState.FAULT, CellState.STOPPED))
        cell.stop()
        ticker.run(until=clock.now() + STOP_GRACE_S,
                   stop=lambda: cell.state in (CellState.STOPPED, CellState.FAULT))
    finally:
        hal.close()
    return got


def _truth(world: Any, cal: Calibration, size: tuple[int, int]) -> list[dict[str, Any]]:
    """Parts on the belt whose silhouette reaches into the image, with where they are in
    pixels and whether they lie wholly inside it (the locator skips border blobs)."""
    w, h = size
    rows = []
    by_id = {p.id: p for p in world.on_horizontal.values()}
    for row in world.truth():
        part = by_id[row["id"]]
        # the outer ring: holes lie inside it (and would put NaN rows in the bounds)
        outline = place_outline(outer(part.outline), row["x_mm"], row["y_mm"],
                                row["angle_deg"])
        px = cal.mm_to_px(outline)
        lo, hi = px.min(axis=0), px.max(axis=0)
        if hi[0] < -0.5 or hi[1] < -0.5 or lo[0] > w - 0.5 or lo[1] > h - 0.5:
            continue
        u, v = cal.mm_to_px(np.array([[row["x_mm"], row["y_mm"]]]))[0]
        rows.append({
            "id": row["id"], "type": row["type"], "pose": row["pose"],
            "pickable": row["pickable"], "singulated": row["singulated"],
            "x_mm": round(row["x_mm"], 4), "y_mm": round(row["y_mm"], 4),
            "angle_deg": round(row["angle_deg"], 4),
            "u_px": round(float(u), 3), "v_px": round(float(v), 3),
            "whole": bool(lo[0] >= 1 and lo[1] >= 1 and hi[0] <= w - 2 and hi[1] <= h - 2),
            "gap_mm": _gap(world, part, row),
        })
    return rows


def _gap(world: Any, part: Any, row: dict[str, Any]) -> float | None:
    """Centre distance minus both circumradii to the nearest other part (a lower bound on
    the clearance), or None if alone: touching-but-not-quite parts merge in the image."""
    best = math.inf
    for other in world.on_horizontal.values():
        if other.id == part.id:
            continue
        ox, oy = world.part_xy(other, world.t)
        d = math.hypot(ox - row["x_mm"], oy - row["y_mm"]) - part.radius - other.radius
        best = min(best, d)
    return None if best == math.inf else round(best, 3)
