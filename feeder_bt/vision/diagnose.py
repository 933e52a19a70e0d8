"""Why a recipe found no part in an image: for `feeder locate` and `feeder check --images`.

Says what the segmentation saw, in the recipe's words: no foreground at all (and whether
the other ``vision.foreground`` would have found the parts, or how far the difference
image falls short of the threshold), or blobs that were all rejected, grouped by reason
(the border, ``min_area_mm2``, or the class nearest them and the range they are outside),
each kind of reason once and every line short; blobs of several times a class's area are
parts touching, and only a blob spanning the image is the belt passing the threshold.
"""

from __future__ import annotations

import dataclasses
from collections import Counter

import numpy as np

from feeder_bt.vision.locator import LocateResult, Locator
from feeder_bt.vision.watch import reason_kind, short, touching

SPAN = 0.95                 # a blob this much of the image's width and height spans it


def why_nothing(locator: Locator, image: np.ndarray, result: LocateResult,
                golden: np.ndarray | None = None) -> list[str]:
    """Lines saying why ``result`` (``locator.locate(image)``) holds no part; [] if it has
    one. ``golden``: the golden image the locator was given, if any."""
    if result.parts:
        return []
    recipe = locator.recipe
    if result.rejected:
        reasons = Counter(_short(d.reason) for d in result.rejected)   # by kind
        lines = [short(f"{n} blob(s) rejected: {reason}") for reason, n in reasons.most_common()]
        if all(d.reason == "too small" for d in result.rejected):
            lines.append(f"every blob is below min_area_mm2 {recipe.min_area_mm2:g}")
        clumps = [(k, d) for d in result.rejected if (k := touching(d.reason)) is not None]
        if clumps:
            k, d = max(clumps, key=lambda c: c[0])
            cls = d.reason.split(": ", 1)[0].removeprefix("no class; nearest ")
            lines.append(short(f"{len(clumps)} blob(s) measure up to {k:.1f}x {cls}'s largest "
                               f"area: parts touching each other — spread them (a slower "
                               f"incline) or set vision.split_touching: true"))
        elif _belt_is_foreground(result, image.shape[:2]):
            frame_mm2 = image.shape[0] * image.shape[1] * locator.calibration.mm2_per_px2
            big = max(d.features.get("area_mm2", 0.0) for d in result.rejected)
            lines.append(f"one blob covers {100 * big / frame_mm2:.0f} % of the image: the "
                         f"belt itself passes the threshold (foreground: "
                         f"{recipe.foreground}) — are the parts {_other(recipe)}er than the "
                         f"belt (vision.foreground), or is the threshold too low?")
        return lines
    lines = [f"no foreground: nothing in the image passes the threshold with "
             f"foreground: {recipe.foreground}"]
    other = _other(recipe)
    flipped = type(locator)(dataclasses.replace(recipe, foreground=other), locator.parts,
                            locator.calibration) if type(locator) is Locator else None
    if flipped is not None:
        if golden is not None:
            flipped.set_golden(golden)
        alt = flipped.locate(image)
        if alt.parts or alt.rejected:
            lines.append(f"with foreground: {other} the same recipe finds {len(alt.parts)} "
                         f"part(s) and {len(alt.rejected)} other blob(s): the parts look "
                         f"{other}er than the belt — set vision.foreground: {other}")
            return lines
    th = recipe.threshold
    if th.method in ("fixed", "otsu"):
        diff = locator._diff(image)
        lines.append(f"the largest difference from the belt is {int(diff.max())} grey "
                     f"levels; the threshold is {th.value:g}")
    return lines


def _belt_is_foreground(result: LocateResult, shape: tuple[int, int]) -> bool:
    """Whether a blob covers over half the image and spans it edge to edge both ways: the
    belt itself, not parts (a clump of touching parts, however large, leaves belt around
    it)."""
    h, w = shape
    for b in result.blobs:
        _, _, bw, bh = b.box
        if bw >= SPAN * w and bh >= SPAN * h and \
                b.area_px > 0.5 * h * w:
            return True
    return False


def _other(recipe) -> str:
    return "light" if recipe.foreground == "dark" else "dark"


def _short(reason: str) -> str:
    """A reject reason without the blob's own figures, so that alike reasons group: the
    class's range stays (it is the same for every blob), the rest by kind
    (``watch.reason_kind``)."""
    if reason.startswith("no class; nearest "):
        head, _, tail = reason.partition(": ")
        feature = tail.split(" ", 1)[0]
        rng = tail[tail.find(" not in "):] if " not in " in tail else ""
        return f"{head}: {feature} out of range{rng.replace(' not in', '')}"
    return reason_kind(reason)
