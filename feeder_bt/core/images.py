"""Image files read and written with one-line errors naming the file: the commands', the
calibration's and the simulated camera's one way to touch an image on disk."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from feeder_bt.core.didyoumean import hint
from feeder_bt.core.errors import FeederError


class BadInput(FeederError):
    """A missing or unreadable input file or a wrong argument: exit 2, like a YAML mistake."""

    exit_code = 2


def read_image(path: str | Path) -> np.ndarray:
    """A grey uint8 image from a PNG/JPG/BMP file, or a one-line error naming the file."""
    p = Path(path)
    if not p.is_file():
        raise BadInput(f"{p}: image not found{hint(p)}")
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise BadInput(f"{p}: cannot read as an image (PNG, JPG or BMP)")
    return img


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an image, creating its folder; a failure is one line naming the file."""
    p = Path(path)
    try:
        p.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise BadInput(f"{p.parent}: cannot create folder: {e.strerror or e}") from None
    if not cv2.imwrite(str(p), image):
        raise BadInput(f"{p}: cannot write image")
