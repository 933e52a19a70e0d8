"""``feeder commission camera`` steps of a pylon camera (``camera.source: pylon:...``):
the camera is found, each trigger brings exactly its own frame, the exposure does not
smear a moving part, and the calibration views are grabbed to files.

Motion blur: a part moving at ``v`` mm/s during an exposure of ``t`` s smears over
``v t / s`` pixels (``s`` mm per pixel); at half a pixel or more the edges the locator
fits move, so the step refuses an exposure at or over ``0.5 s / v`` and says that limit.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path
from typing import Any

from feeder_bt.cli.commission.steps import Asker, Report, try_step
from feeder_bt.core.model import CellSpec

TRIGGER_FRAMES = 10          # triggers the trigger step fires
MAX_BLUR_PX = 0.5


def belt_speed(cell: CellSpec, opts: argparse.Namespace) -> float:
    """The fastest the belt runs under the camera: ``--belt-mm-s``, else the latch
    conveyor's ``max_mm_s``."""
    if getattr(opts, "belt_mm_s", None):
        return float(opts.belt_mm_s)
    axis = cell.galil.latch_axis.upper()
    name = next((n for n, a in cell.galil.axes.items() if a.upper() == axis), "horizontal")
    conv = cell.conveyors.get(name) or next(iter(cell.conveyors.values()))
    return conv.max_mm_s


def blur(exposure_ms: float, speed_mm_s: float, mm_per_px: float) -> dict[str, Any]:
    """The smear of an exposure at a belt speed, and the longest exposure under the limit."""
    px = exposure_ms / 1000.0 * speed_mm_s / mm_per_px
    longest_ms = 1000.0 * MAX_BLUR_PX * mm_per_px / speed_mm_s
    return {"ok": px < MAX_BLUR_PX, "blur_px": round(px, 3), "limit_px": MAX_BLUR_PX,
            "exposure_ms": round(exposure_ms, 4), "belt_mm_s": speed_mm_s,
            "mm_per_px": mm_per_px, "longest_exposure_ms": round(longest_ms, 4)}


def enumerate_step(cell: CellSpec) -> dict[str, Any]:
    from feeder_bt.hal.camera.pylon import SCHEME, list_cameras
    cams = list_cameras()
    serial = cell.camera.source[len(SCHEME):].strip()
    found = [c for c in cams if not serial or c["serial"] == serial]
    return {"ok": bool(found), "wanted": serial or "the first camera", "cameras": cams,
            **({} if found else {"error": "no such camera (PYLON_CAMEMU=N adds emulated "
                                          "ones)"})}


def trigger_step(src: Any) -> dict[str, Any]:
    """Fire the cell's trigger ``TRIGGER_FRAMES`` times: each must bring one frame, the
    camera's frame counter one up each time, nothing extra."""
    before = dict(src.counts())
    times = []
    errors: list[str] = []
    for _ in range(TRIGGER_FRAMES):
        t0 = time.monotonic()
        try:
            src.capture()
            times.append(time.monotonic() - t0)
        except Exception as e:                  # noqa: BLE001 - recorded, the step fails
            errors.append(str(e))
    src.prepare()                               # a stray frame after the last trigger
    after = src.counts()
    got = {k: after[k] - before[k] for k in after}
    out: dict[str, Any] = {
        "ok": not errors and got["frames"] == TRIGGER_FRAMES and got["lost_frames"] == 0
        and got["extra_triggers"] == 0,
        "trigger": src.settings.trigger, "triggers": TRIGGER_FRAMES, **got,
        "frame_counter": src.last_id}
    if times:
        out.update(trigger_to_frame_ms_mean=round(1000 * sum(times) / len(times), 2),
                   trigger_to_frame_ms_max=round(1000 * max(times), 2))
    if errors:
        out["error"] = errors[0]
    return out


def exposure_step(cell: CellSpec, src: Any, opts: argparse.Namespace) -> dict[str, Any]:
    """The exposure the camera really has (read back, SFNC 1 or 2 name), against the
    belt's speed; with a line trigger also how far the belt runs between the latched pulse
    and the exposure (the line's debouncer and trigger delay)."""
    speed = belt_speed(cell, opts)
    out = blur(src.exposure_us() / 1000.0, speed, cell.camera.calibration.mm_per_px)
    lag_us = src.trigger_lag_us()
    if lag_us:
        out.update(trigger_lag_us=lag_us, belt_mm_after_latch=round(speed * lag_us / 1e6, 3))
    return out


def views_step(ask: Asker, src: Any, folder: Path, n: int) -> dict[str, Any]:
    """Calibration views for ``feeder calibrate camera --image``: the person lays or holds
    the target, a frame is grabbed and written for each."""
    from feeder_bt.core.images import write_image
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for k in range(1, n + 1):
        ask(f"view.{k}", f"Calibration view {k} of {n}: lay or hold the target in a new "
                         "place in the view, then press Enter")
        path = folder / f"view{k:02d}.png"
        write_image(str(path), src.capture())
        files.append(str(path))
    return {"ok": len(files) == n, "views": files}


def pylon_steps(cell: CellSpec, ask: Asker, report: Report, opts: argparse.Namespace,
                src: Any, wanted: set[str]) -> bool:
    """The pylon steps after ``camera.grab`` opened ``src``; False when one failed."""
    ok = True
    if "trigger" in wanted:
        ok &= try_step(report, "camera.pylon.trigger", lambda: trigger_step(src))
    if "exposure" in wanted:
        ok &= try_step(report, "camera.pylon.exposure", lambda: exposure_step(cell, src, opts))
    if "views" in wanted and getattr(opts, "views", 0):
        folder = Path(opts.views_dir or f"{Path(opts.report or 'commission-camera').stem}"
                                         "-views")
        ok &= try_step(report, "camera.pylon.views",
                       lambda: views_step(ask, src, folder, opts.views))
    return ok
