"""Time the simulator's renderer and the OpenCV locator on fixed-seed frames.

    python benchmarks/vision_bench.py [--frames 300] [--parts 6] [--out PATH]

Renders frames of about six singulated parts (lenses and cut-corner squares, the
``lenses_and_squares`` recipe), times ``Renderer.render`` and ``Locator.locate`` per frame,
checks each located part against the truth, and writes p50/p99 ms and accuracy as JSON.
Comparisons with scikit-image and cv2.SimpleBlobDetector pipelines come later.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from feeder_bt.geometry import circumradius, place_outline, pose_outline, wrap_deg  # noqa: E402
from feeder_bt.hal.sim.render import Renderer  # noqa: E402
from feeder_bt.scenario import load_cell, load_scenario  # noqa: E402
from feeder_bt.scenario.model import CameraSpec, PartSpec, VisionRecipe  # noqa: E402
from feeder_bt.vision.calibration import Calibration  # noqa: E402
from feeder_bt.vision.locator import Locator  # noqa: E402


def load(name: str = "lenses_and_squares") -> tuple[dict[str, PartSpec], VisionRecipe]:
    """Parts and recipe of a scenario (the benchmark times vision only)."""
    scenario, _ = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    return scenario.parts, scenario.vision


def _layout(rng: np.random.Generator, parts: dict[str, PartSpec], cal: Calibration,
            cam: CameraSpec, n: int) -> list[dict]:
    """Up to ``n`` parts wholly inside the image and apart (singulated)."""
    placed: list[dict] = []
    for _ in range(n * 60):
        if len(placed) == n:
            break
        name = str(rng.choice(sorted(parts)))
        part = parts[name]
        poses = sorted(part.poses)
        pr = np.array([part.poses[p].probability for p in poses])
        pose = str(rng.choice(poses, p=pr / pr.sum()))
        outline = pose_outline(part, pose)
        x, y = cal.px_to_mm([[rng.uniform(0, cam.width_px), rng.uniform(0, cam.height_px)]])[0]
        angle = float(rng.uniform(-180, 180))
        o = place_outline(outline, x, y, angle)
        px = cal.mm_to_px(o)
        if px.min() < 3 or px[:, 0].max() > cam.width_px - 4 or px[:, 1].max() > cam.height_px - 4:
            continue
        r = circumradius(outline)
        if any(math.hypot(x - q["x"], y - q["y"]) < r + q["r"] + 8 for q in placed):
            continue
        placed.append({"part": name, "pose": pose, "x": x, "y": y, "angle": angle, "r": r,
                       "outline": o})
    return placed


def _pct(v: list[float], q: float) -> float:
    return round(float(np.percentile(v, q)), 4)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--parts", type=int, default=6)
    ap.add_argument("--seed", type=int, default=2024)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results" / "vision.json")
    args = ap.parse_args(argv)

    cam = load_cell(ROOT / "cells" / "sim.yaml").camera     # the simulated cell's camera
    cal = Calibration(cam.calibration)
    renderer = Renderer(cam)
    parts, recipe = load()
    locator = Locator(recipe, parts, cal)
    rng = np.random.default_rng(args.seed)
    locator.set_golden(renderer.golden(rng))

    render_ms, locate_ms, pos_err, ang_err = [], [], [], []
    wrong = missed = extra = 0
    for _ in range(args.frames):
        layout = _layout(rng, parts, cal, cam, args.parts)
        outlines = [p["outline"] for p in layout]
        t0 = time.perf_counter()
        img = renderer.render(outlines, rng)
        t1 = time.perf_counter()
        res = locator.locate(img)
        t2 = time.perf_counter()
        render_ms.append((t1 - t0) * 1e3)
        locate_ms.append((t2 - t1) * 1e3)
        extra += max(len(res.parts) - len(layout), 0)
        for t in layout:
            near = [d for d in res.parts if math.hypot(d.x_mm - t["x"], d.y_mm - t["y"]) < 10]
            if len(near) != 1:
                missed += 1
                continue
            d = near[0]
            if (d.part, d.pose) != (t["part"], t["pose"]):
                wrong += 1
            pos_err.append(math.hypot(d.x_mm - t["x"], d.y_mm - t["y"]))
            if t["part"] == "square":
                ang_err.append(abs(wrap_deg(d.angle_deg - t["angle"])))

    report = {
        "benchmark": "vision",
        "frames": args.frames,
        "parts_per_frame": args.parts,
        "image_px": [cam.width_px, cam.height_px],
        "render_ms": {"p50": _pct(render_ms, 50), "p99": _pct(render_ms, 99)},
        "locate_ms": {"p50": _pct(locate_ms, 50), "p99": _pct(locate_ms, 99)},
        "accuracy": {
            "parts": len(pos_err) + missed,
            "missed": missed, "misclassified": wrong, "extra": extra,
            "position_mm": {"p50": _pct(pos_err, 50), "p99": _pct(pos_err, 99),
                            "max": round(max(pos_err), 4)},
            "square_angle_deg": {"p50": _pct(ang_err, 50), "p99": _pct(ang_err, 99),
                                 "max": round(max(ang_err), 4)},
        },
        "python": platform.python_version(),
        "machine": platform.machine(),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report, indent=2))
    return report


if __name__ == "__main__":
    main()
