"""``feeder recipe suggest``: propose a recipe class's feature ranges from sample images.

Blobs are measured by the locator itself (``Locator.measure_blobs``: the same segmentation
and features as feeding), so the ranges fit what the cell will measure. Good images show the
part in the pose to learn; the blobs that are not it (touching pairs, the other poses) are
told apart as area outliers and count as bad samples, with every blob of the ``--bad``
images. Each feature's range is the good samples' min/max widened by a margin; features are
kept only while they exclude bad samples that the kept ones let through (area always kept),
so the snippet is as short as the samples allow.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass

import numpy as np

from feeder_bt.cli.inputs import check_size, load_golden, scenario_locator
from feeder_bt.core.geometry import outer, polygon_area, pose_outline, rings
from feeder_bt.core.images import BadInput, read_image
from feeder_bt.core.model import Scenario
from feeder_bt.tuning.ranges import PREFERRED
from feeder_bt.tuning.ranges import fmt as _fmt
from feeder_bt.tuning.ranges import inside as _inside
from feeder_bt.tuning.ranges import spread as _spread
from feeder_bt.tuning.ranges import widen as _widen
from feeder_bt.vision.features import FEATURES
from feeder_bt.vision.locator import Locator

FEW_SAMPLES = 20            # fewer good blobs than this: say the ranges may be too narrow
OUTLIER_AREA = 0.20        # good-image blobs further than this from the median area are not samples
MAX_EXTRA = 3              # at most this many features besides the area


@dataclass
class Suggestion:
    part: str
    pose: str
    pickable: bool
    ranges: dict[str, tuple[float, float]]
    good: int
    bad: int
    bad_let_through: int

    def yaml(self) -> str:
        """A ``vision.classes`` entry to paste into the scenario."""
        items = [f"part: {self.part}", f"pose: {self.pose}",
                 f"pickable: {'true' if self.pickable else 'false'}"]
        items += [f"{k}: [{_fmt(lo)}, {_fmt(hi)}]" for k, (lo, hi) in self.ranges.items()]
        return "- {" + ", ".join(items) + "}"


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("recipe", help="tools for vision recipes")
    sub = p.add_subparsers(dest="recipe_command", required=True, metavar="COMMAND",
                           parser_class=type(p))
    s = sub.add_parser("suggest", help="propose feature ranges for a class from sample images")
    s.add_argument("scenario", help="scenario YAML (its recipe segments the images)")
    s.add_argument("--good", nargs="+", required=True, metavar="IMAGE",
                   help="images showing the part in the pose (other blobs are told apart)")
    s.add_argument("--bad", nargs="+", default=[], metavar="IMAGE",
                   help="images of things the class must not match")
    s.add_argument("--golden", metavar="IMAGE", help="the empty, lit belt")
    s.add_argument("--clusters", action="store_true",
                   help="the images show several parts or poses: propose one class per "
                        "cluster of feature values, named after the nearest pose")
    s.add_argument("--part", help="part name (default: the scenario's only part)")
    s.add_argument("--pose", help="pose name (default: the part's first pickable pose)")
    s.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    s.set_defaults(handler=cmd_suggest)
    return p


def cmd_suggest(args: argparse.Namespace) -> int:
    scenario, _, locator = scenario_locator(args.scenario, args.cell)
    golden = load_golden(locator, args.golden, "feeder recipe suggest")
    good = _samples(locator, args.good, golden)
    bad = _samples(locator, args.bad, golden)
    if args.clusters:
        for sug in suggest_clusters(good, bad, scenario):
            print(f"# {sug.good} blob(s) in this cluster; the class lets through "
                  f"{sug.bad_let_through} other blob(s)")
            print(sug.yaml())
        return 0
    part, pose = _part_pose(scenario, args.part, args.pose)
    spec = scenario.parts[part]
    nominal = polygon_area(outer(pose_outline(spec, pose)))
    sug = suggest(good, bad, part, pose, spec.poses[pose].pickable, nominal_area=nominal)
    print(f"# {sug.good} good blob(s), {sug.bad} bad; the class lets through "
          f"{sug.bad_let_through} bad", file=sys.stderr)
    if sug.good < FEW_SAMPLES:      # a part seen in several frames is one sample many times
        print(f"# only {sug.good} good blob(s) of {part}/{pose}: its ranges may be too "
              f"narrow for the turns and places it was not seen in; give more images "
              f"(at least {FEW_SAMPLES} blobs)", file=sys.stderr)
    print(sug.yaml())
    return 0


def suggest(good: list[dict[str, float]], bad: list[dict[str, float]], part: str, pose: str,
            pickable: bool, nominal_area: float | None = None) -> Suggestion:
    """Ranges for ``part``/``pose`` from feature dicts of good-image and bad-image blobs.

    The samples are the good-image blobs near ``nominal_area`` (the pose's silhouette area
    from the scenario's outline), or near the median area if none is near it; the rest of
    the good-image blobs are other poses or touching parts and count as bad.
    """
    if not good:
        raise BadInput("no whole blobs in the --good images (all touch the border or are "
                       "smaller than min_area_mm2)")
    areas = np.array([f["area_mm2"] for f in good])
    centre = float(np.median(areas))
    if nominal_area and np.any(np.abs(areas - nominal_area) <= OUTLIER_AREA * nominal_area):
        centre = nominal_area
    near = np.abs(areas - centre) <= OUTLIER_AREA * centre
    samples = [f for f, k in zip(good, near, strict=True) if k]
    negatives = [f for f, k in zip(good, near, strict=True) if not k] + list(bad)
    widened = {name: _widen([f[name] for f in samples]) for name in FEATURES}
    # a count is exact: its range is the counts seen
    widened["holes"] = (min(f["holes"] for f in samples), max(f["holes"] for f in samples))
    chosen = {"area_mm2": widened["area_mm2"]}
    through = [f for f in negatives if _inside(f, chosen)]
    for _ in range(MAX_EXTRA):
        if not through:
            break
        best = max((n for n in PREFERRED if n not in chosen),
                   key=lambda n: (sum(not _inside(f, {n: widened[n]}) for f in through),
                                  -PREFERRED.index(n)))
        if not any(not _inside(f, {best: widened[best]}) for f in through):
            break
        chosen[best] = widened[best]
        through = [f for f in through if _inside(f, chosen)]
    if len(chosen) == 1:                 # nothing to separate: add the steadiest shape feature
        shape = min(PREFERRED[:4], key=lambda n: _spread(samples, n))
        chosen[shape] = widened[shape]
    return Suggestion(part, pose, pickable, chosen, good=len(samples), bad=len(negatives),
                      bad_let_through=len(through))


#: Scales at which two blobs' features count as alike (``suggest_clusters``).
CLUSTER_SCALE = {"area_mm2": 0.12, "aspect": 0.15, "solidity": 0.08, "holes": 0.5}
MIN_CLUSTER = 3            # smaller clusters are odd blobs (touching parts): not a class


def suggest_clusters(good: list[dict[str, float]], bad: list[dict[str, float]],
                     scenario: Scenario) -> list[Suggestion]:
    """One class per cluster of alike blobs in ``good`` (several parts or poses in one
    image set), each named after the pose whose outline is nearest in area and holes.

    Blobs are alike when their log area, log aspect, solidity and hole count all differ by
    less than ``CLUSTER_SCALE``; clusters are the connected groups of alike blobs (single
    linkage, so the order of the samples does not matter). Each cluster's ranges come from
    ``suggest`` with every other blob as a bad sample.
    """
    if not good:
        raise BadInput("no whole blobs in the --good images (all touch the border or are "
                       "smaller than min_area_mm2)")
    z = np.array([[math.log(max(f["area_mm2"], 1e-9)) / CLUSTER_SCALE["area_mm2"],
                   math.log(max(f["aspect"], 1e-9)) / CLUSTER_SCALE["aspect"],
                   f["solidity"] / CLUSTER_SCALE["solidity"],
                   f["holes"] / CLUSTER_SCALE["holes"]] for f in good])
    n = len(good)
    label = list(range(n))

    def find(i: int) -> int:
        while label[i] != i:
            label[i] = label[label[i]]
            i = label[i]
        return i

    near = np.abs(z[:, None, :] - z[None, :, :]).max(axis=2) < 1.0
    for i, j in zip(*np.nonzero(np.triu(near, 1)), strict=True):
        label[find(int(i))] = find(int(j))
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(find(i), []).append(i)
    clusters = sorted((g for g in groups.values() if len(g) >= MIN_CLUSTER),
                      key=lambda g: -len(g))
    if not clusters:
        raise BadInput(f"no cluster of at least {MIN_CLUSTER} alike blobs in the --good images")
    poses = [(pn, qn, polygon_area(outer(o)), len(rings(o)) - 1, spec.poses[qn].pickable)
             for pn, spec in scenario.parts.items() for qn in spec.poses
             for o in [pose_outline(spec, qn)]]
    out = []
    for g in clusters:
        members = [good[i] for i in g]
        area = float(np.median([f["area_mm2"] for f in members]))
        holes = round(float(np.median([f["holes"] for f in members])))
        part, pose, _, _, pickable = min(
            poses, key=lambda p: (p[3] != holes, abs(p[2] - area) / max(p[2], 1e-9)))
        others = [good[i] for i in range(n) if i not in set(g)] + list(bad)
        sug = suggest(members, others, part, pose, pickable, nominal_area=None)
        if any(f["holes"] for f in good) and "holes" not in sug.ranges:
            sug.ranges["holes"] = (float(holes), float(holes))
            sug.bad_let_through = sum(_inside(f, sug.ranges) for f in others)
        out.append(sug)
    return out


def _samples(locator: Locator, paths: list[str], golden: np.ndarray | None
             ) -> list[dict[str, float]]:
    out = []
    for path in paths:
        img = read_image(path)
        check_size(path, img, golden)
        out += [d.features for d in locator.measure_blobs(img) if not d.reason]
    return out


def _part_pose(scenario: Scenario, part: str | None, pose: str | None) -> tuple[str, str]:
    parts = scenario.parts
    if part is None:
        if len(parts) != 1:
            raise BadInput(f"the scenario has {len(parts)} parts: give --part "
                           f"({', '.join(parts)})")
        part = next(iter(parts))
    if part not in parts:
        raise BadInput(f"--part {part!r}: not in the scenario; parts: {', '.join(parts)}")
    poses = parts[part].poses
    if pose is None:
        pose = next(n for n, p in poses.items() if p.pickable)
    if pose not in poses:
        raise BadInput(f"--pose {pose!r}: part {part!r} has poses {', '.join(poses)}")
    return part, pose
