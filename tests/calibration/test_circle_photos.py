"""On real photos of a circle grid the
project uses at least all but one of the views plain OpenCV uses, with a reprojection rms
at most 1.5 times OpenCV's and a k1 of the same sign.

The photos are OpenCV's own test photos from opencv_extra (tests/data/README.md): nine
webcam views of three asymmetric grids (7x13, 5x5, 3x9, three views each) and six
wide-angle views of a symmetric 7x7 grid. Plain OpenCV (``findCirclesGrid`` with its
default blob detector, ``calibrateCamera`` with its default flags) runs on the same photos
here, so the comparison is measured, not copied.

The physical pitch of these boards is not known; it does not matter: a flat board twice as
large seen twice as far gives the same image, so the intrinsics do not depend on it (each
view's distance absorbs it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np

from feeder_bt.calibration.intrinsics import calibrate_views, find_views
from feeder_bt.calibration.targets import Target
from feeder_bt.cli.main import main

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data"
SIM_CELL = ROOT / "cells" / "sim.yaml"
# the three boards of the asymmetric set: (points per row, rows) -> their photos
ACIRCLES = {(7, 13): (1, 2, 3), (5, 5): (4, 5, 6), (3, 9): (7, 8, 9)}
CIRCLES = [DATA / "circles_7x7" / f"circles{i}.png" for i in range(6, 12)]


def _acircles(ids: tuple[int, ...]) -> list[Path]:
    return [DATA / "acircles" / f"acircles{i}.png" for i in ids]


def _plain_opencv(sets: list[tuple[list[Path], tuple[int, int]]], asymmetric: bool
                  ) -> tuple[list[str], float, np.ndarray, np.ndarray]:
    """OpenCV as its calibration sample uses it: the photos it finds the grid in, its rms,
    camera matrix and distortion. ``sets``: photos and their board (points per row, rows)."""
    flag = cv2.CALIB_CB_ASYMMETRIC_GRID if asymmetric else cv2.CALIB_CB_SYMMETRIC_GRID
    names, obj, img = [], [], []
    for paths, (nx, ny) in sets:
        o = np.zeros((nx * ny, 3), np.float32)
        if asymmetric:          # OpenCV's sample: x = (2 col + row % 2) s, y = row s
            o[:, :2] = [[2 * c + r % 2, r] for r in range(ny) for c in range(nx)]
        else:
            o[:, :2] = [[c, r] for r in range(ny) for c in range(nx)]
        for p in paths:
            found, pts = cv2.findCirclesGrid(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE),
                                             (nx, ny), flags=flag)
            if found:
                names.append(p.name)
                obj.append(o)
                img.append(pts)
    rms, k, dist, _, _ = cv2.calibrateCamera(obj, img, (640, 480), None, None)
    return names, rms, k, dist.ravel()


def _cli_json(capsys, kind: str, board: tuple[int, int], dot: float, paths: list[Path]
              ) -> dict:
    args = ["calibrate", "camera", str(SIM_CELL), "--target", kind,
            "--board", f"{board[0]}x{board[1]}", "--square", "20", "--dot", str(dot),
            "--no-prior", "--json", "--max-belt-mm", "100"]   # a hand-held board: no belt
    for p in paths:
        args += ["--image", str(p)]
    capsys.readouterr()
    assert main(args) == 0
    return json.loads(capsys.readouterr().out)


def _assert_goal(used: list[str], rms: float, fx: float, k1: float,
                 cv_used: list[str], cv_rms: float, cv_k: np.ndarray, cv_dist: np.ndarray
                 ) -> None:
    assert len(cv_used) >= 3                                  # OpenCV calibrates from them
    assert len(set(used) & set(cv_used)) >= len(cv_used) - 1   # all but one, at least
    assert rms <= 1.5 * cv_rms
    assert math.copysign(1, k1) == math.copysign(1, cv_dist[0])
    assert abs(fx - cv_k[0, 0]) < 0.02 * cv_k[0, 0]          # not asked; holds here


def test_real_asymmetric_grid_photos_through_the_cli(capsys):
    paths = _acircles(ACIRCLES[(7, 13)])
    cv_used, cv_rms, cv_k, cv_dist = _plain_opencv([(paths, (7, 13))], asymmetric=True)
    assert len(cv_used) == 3
    d = _cli_json(capsys, "acircles", (7, 13), 6.0, paths)
    used = [Path(n).name for n in d["views_used"]]
    assert d["views_rejected"] == []
    _assert_goal(used, d["rms_px"], d["fx"], d["dist"][0], cv_used, cv_rms, cv_k, cv_dist)


def test_real_symmetric_grid_photos_of_a_wide_lens_through_the_cli(capsys):
    cv_used, cv_rms, cv_k, cv_dist = _plain_opencv([(CIRCLES, (7, 7))], asymmetric=False)
    assert len(cv_used) == 6 and cv_dist[0] < -0.3                   # strong barrel
    d = _cli_json(capsys, "circles", (7, 7), 8.0, CIRCLES)
    used = [Path(n).name for n in d["views_used"]]
    assert d["views_rejected"] == []
    _assert_goal(used, d["rms_px"], d["fx"], d["dist"][0], cv_used, cv_rms, cv_k, cv_dist)
    assert abs(d["dist"][0] - cv_dist[0]) < 0.02                # the same barrel


def test_nine_views_of_three_asymmetric_boards_calibrate_one_camera():
    """Three views of one small board leave the lens loose (OpenCV's own focal length from
    the 3x9 board alone is a third short of the nine views'); each view carries its own
    board, so all nine calibrate the webcam together."""
    sets = [(_acircles(ids), size) for size, ids in ACIRCLES.items()]
    cv_used, cv_rms, cv_k, cv_dist = _plain_opencv(sets, asymmetric=True)
    assert len(cv_used) == 9
    views = []
    for paths, (nx, ny) in sets:
        found, rejected = find_views([(p.name, cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
                                      for p in paths], Target("acircles", nx, ny, 20.0, 6.0))
        assert rejected == []
        views += found
    model = calibrate_views(views, Target("acircles", 7, 13, 20.0, 6.0), (640, 480))
    assert model.dropped == []
    _assert_goal(model.used, model.rms_px, model.fx, model.dist[0], cv_used, cv_rms, cv_k,
                 cv_dist)
    assert abs(model.fy - cv_k[1, 1]) < 0.02 * cv_k[1, 1]
    assert 0 < model.std["k1"] < abs(model.dist[0]) / 5       # k1 > 0 is measured, not noise
