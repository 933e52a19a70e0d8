"""What the image tools share: one-line input errors, image reading, a scenario's locator."""

from __future__ import annotations

import sys

import numpy as np

from feeder_bt.config import load_scenario
from feeder_bt.core.images import BadInput, read_image
from feeder_bt.core.model import CellSpec, Scenario
from feeder_bt.trees.leaves import leaf_class
from feeder_bt.vision.locator import Locator
from feeder_bt.vision.pixels import Calibration


def scenario_locator(path: str, cell: str | None = None
                     ) -> tuple[Scenario, CellSpec, Locator]:
    """The locator the cell would build for this scenario (its ``vision.leaf`` if it has one)."""
    scenario, cell_spec = load_scenario(path, cell)
    cls = leaf_class(scenario, "vision.leaf") or Locator
    locator = cls(scenario.vision, scenario.parts, Calibration(cell_spec.camera.calibration))
    return scenario, cell_spec, locator


def load_golden(locator: Locator, golden: str | None, command: str) -> np.ndarray | None:
    """Give the locator its golden image. Says so on stderr when the recipe wants one and
    none was given (subtraction is then off), or when one is given but not used."""
    if not locator.recipe.golden_image:
        if golden:
            print(f"{command}: note: the recipe does not subtract a golden image; "
                  "--golden ignored", file=sys.stderr)
        return None
    if golden is None:
        print(f"{command}: note: the recipe subtracts a golden image but no --golden was "
              "given: thresholding the raw image instead", file=sys.stderr)
        return None
    img = read_image(golden)
    locator.set_golden(img)
    return img


def check_size(path: str, image: np.ndarray, golden: np.ndarray | None) -> None:
    """Subtraction needs the golden image and the frame to be the same size."""
    if golden is not None and golden.shape != image.shape:
        raise BadInput(f"{path}: image is {image.shape[1]}x{image.shape[0]} px but the "
                       f"golden image is {golden.shape[1]}x{golden.shape[0]} px")
