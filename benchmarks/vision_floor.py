"""How much of our locator's time is OpenCV's own work: the floor no Python glue can cut.

    python benchmarks/vision_floor.py [--frames 200] [--repeats 5] [--scenarios lenses squares]

``vision_bench.py`` sets our locator against ``cv2.SimpleBlobDetector`` on the same frames.
This asks what is left to gain: on each frame it counts the thread CPU time our locator
spends inside OpenCV calls (every ``cv2`` function, each call timed around itself; the
timer's own cost, measured on an empty call, taken off), and the locator's and the
detector pipeline's whole thread CPU time. If the OpenCV calls alone take longer than the
detector's whole frame, no rewrite of the Python between them reaches the detector; only
doing less image work (no morphology, no sub-pixel face) or moving the per-blob work into
compiled code would.

Thread CPU time (``time.thread_time_ns``), not wall time: this machine's wall-clock time
moves by 20-30 % between runs. The pipelines take turns frame by frame; each frame's best
of ``--repeats`` passes, then the median over frames. Writes
``benchmarks/results/vision_floor.json``.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from vision_bench import BlobPipeline, Ours, write_report  # noqa: E402

from feeder_bt.cli.render_cmd import render_frames  # noqa: E402
from feeder_bt.config import load_scenario  # noqa: E402
from feeder_bt.vision.pixels import Calibration  # noqa: E402


class OpenCvClock:
    """While entered, every ``cv2`` function adds its thread CPU time to ``ns``."""

    def __init__(self) -> None:
        self.ns = 0
        self.calls = 0
        self._orig = {n: f for n in dir(cv2) if not n.startswith("_")
                      and callable(f := getattr(cv2, n)) and type(f).__name__ ==
                      "builtin_function_or_method"}

    def _wrap(self, f):
        clock = time.thread_time_ns

        def timed(*a, **k):
            t0 = clock()
            r = f(*a, **k)
            self.ns += clock() - t0
            self.calls += 1
            return r
        return timed

    def __enter__(self) -> OpenCvClock:
        for n, f in self._orig.items():
            setattr(cv2, n, self._wrap(f))
        return self

    def __exit__(self, *exc) -> None:
        for n, f in self._orig.items():
            setattr(cv2, n, f)


def _empty_call_ns() -> float:
    """What one timed call of a do-nothing OpenCV function adds (the timer's own cost)."""
    clock = OpenCvClock()
    pts = np.zeros((1, 1, 2), np.int32)
    best = []
    with clock:
        for _ in range(5):
            clock.ns = clock.calls = 0
            for _ in range(2000):
                cv2.boundingRect(pts)
            best.append(clock.ns / clock.calls)
    t0 = time.thread_time_ns()
    for _ in range(2000):
        cv2.boundingRect(pts)
    bare = (time.thread_time_ns() - t0) / 2000
    return max(min(best) - bare, 0.0)


def bench_scenario(name: str, n_frames: int, repeats: int, seed: int, overhead: float) -> dict:
    path = ROOT / "scenarios" / f"{name}.yaml"
    scenario, cell = load_scenario(path)
    cal = Calibration(cell.camera.calibration)
    got = render_frames(str(path), n_frames, seed)
    ours = Ours(scenario.vision, scenario.parts, cal, got.golden)
    blob = BlobPipeline(scenario.vision, scenario.parts, cal, got.golden)
    clock = OpenCvClock()
    rows = {"ours_us": [], "ours_opencv_us": [], "opencv_calls": [], "blob_us": []}
    for i, img in enumerate(got.frames):
        best = {"ours": np.inf, "cv": np.inf, "blob": np.inf}
        calls = 0
        for rep in range(repeats):
            for which in (("ours", "blob") if (i + rep) % 2 else ("blob", "ours")):
                if which == "blob":
                    t0 = time.thread_time_ns()
                    blob(img)
                    best["blob"] = min(best["blob"], time.thread_time_ns() - t0)
                    continue
                t0 = time.thread_time_ns()
                ours(img)
                best["ours"] = min(best["ours"], time.thread_time_ns() - t0)
                with clock:
                    clock.ns = clock.calls = 0
                    ours(img)
                calls = clock.calls
                best["cv"] = min(best["cv"], clock.ns - overhead * clock.calls)
        rows["ours_us"].append(best["ours"] / 1e3)
        rows["ours_opencv_us"].append(best["cv"] / 1e3)
        rows["opencv_calls"].append(calls)
        rows["blob_us"].append(best["blob"] / 1e3)
    med = {k: round(float(np.median(v)), 1) for k, v in rows.items()}
    return {"frames": len(got.frames), "median": med,
            "ours_opencv_over_blob": round(med["ours_opencv_us"] / med["blob_us"], 3),
            "ours_over_blob": round(med["ours_us"] / med["blob_us"], 3),
            "glue_share_of_ours": round(1 - med["ours_opencv_us"] / med["ours_us"], 3)}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--scenarios", nargs="*", default=["lenses", "squares"])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path,
                    default=ROOT / "benchmarks" / "results" / "vision_floor.json")
    args = ap.parse_args(argv)
    overhead = _empty_call_ns()
    report = {
        "benchmark": "vision_floor",
        "method": "thread CPU time; each frame's best of the repeats, median over frames; "
                  "pipelines take turns; OpenCV time = sum over every cv2 call of ours, "
                  "less the timer's cost per call",
        "timer_ns_per_call": round(overhead, 1),
        "repeats": args.repeats, "seed": args.seed,
        "scenarios": {n: bench_scenario(n, args.frames, args.repeats, args.seed, overhead)
                      for n in args.scenarios},
        "versions": {"python": platform.python_version(), "numpy": np.__version__,
                     "opencv": cv2.__version__},
        "machine": platform.machine(),
    }
    return write_report(report, args.out)


if __name__ == "__main__":
    main()
