"""``feeder teach``: write a scenario from labelled photos (``tuning.teach``), and with
``--validate`` score it on held-out images against a plain OpenCV pipeline
(``tuning.evaluate``)."""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

from feeder_bt.cli.argtypes import expect_kind
from feeder_bt.cli.inputs import scenario_locator
from feeder_bt.core.images import BadInput, read_image
from feeder_bt.core.model import CellSpec
from feeder_bt.tuning.evaluate import PlainBaseline, held_out, score_finds
from feeder_bt.tuning.labels import Sample, load_coco, load_part_dir
from feeder_bt.tuning.teach import Taught, cell_calibration, teach, write_scenario


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("teach", help="learn a scenario (segmentation, classes, outlines, "
                              "pick points) from labelled photos of the parts")
    p.add_argument("images", nargs="*", metavar="IMAGE",
                   help="photos of the parts as the cell's camera sees them")
    p.add_argument("--labels", metavar="LABELS.json",
                   help="COCO JSON (CVAT, Label Studio, labelme): a box per part, its "
                        "category `part` or `part/pose`")
    p.add_argument("--part", action="append", default=[], metavar="NAME=DIR",
                   help="a folder of photos of one part alone (every blob is that part; "
                        "NAME/POSE=DIR for a pose); may be repeated")
    p.add_argument("--cell", required=True, help="cell description YAML: its camera's "
                   "calibration gives the mm per pixel")
    p.add_argument("--out", required=True, metavar="SCENARIO.yaml",
                   help="the scenario to write")
    p.add_argument("--validate", type=_fraction, metavar="FRACTION",
                   help="hold out this fraction of the labelled images, teach on the rest and "
                        "print the confusion table and each class's precision/recall/F1")
    p.set_defaults(handler=cmd_teach)
    return p


def _fraction(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected a fraction between 0 and 1, got {text!r}") from None
    if not 0 < v < 1:
        raise argparse.ArgumentTypeError(f"expected a fraction between 0 and 1, got {text}")
    return v


def cmd_teach(args: argparse.Namespace) -> int:
    expect_kind(args.cell, "cell", "--cell")
    if args.images and not args.labels:
        raise BadInput("images given without --labels: label them (COCO JSON), or give "
                       "folders of one part each with --part NAME=DIR")
    if args.labels and not args.images:
        raise BadInput(f"--labels {args.labels}: give the images it labels too")
    if not args.images and not args.part:
        raise BadInput("nothing to learn from: give IMAGES with --labels, or --part NAME=DIR")
    labelled = sorted(load_coco(args.labels, args.images), key=lambda s: s.name) \
        if args.images else []
    folders = [s for spec in args.part for s in load_part_dir(spec)]
    cell_spec, cal = cell_calibration(args.cell)
    test: list[Sample] = []
    train = labelled
    if args.validate:
        out = set(held_out(len(labelled), args.validate))
        test = [s for i, s in enumerate(labelled) if i in out]
        train = [s for i, s in enumerate(labelled) if i not in out]
        if not test or not train:
            raise BadInput(f"--validate {args.validate}: {len(labelled)} labelled image(s) "
                           "cannot be split into a teaching and a held-out part")
    taught = teach(train + folders, cal)
    if train:
        taught = _choose_split(taught, train, args.cell, cell_spec)
    seg = taught.segmentation
    print(f"segmentation: {seg.name}: {seg.good} of {seg.labels} labelled part(s) alone, "
          f"{seg.stray} stray blob(s) (best of {taught.tried})")
    if taught.split is not None:
        print(f"split_touching: {'true' if taught.recipe.split_touching else 'false'}: "
              f"F1 {taught.split[1]:.3f} cutting touching parts apart, "
              f"{taught.split[0]:.3f} not, on the teaching images")
    for c, ms in sorted(taught.samples.items()):
        o = taught.outlines[c]
        rg = ", ".join(taught.ranges[c])
        print(f"{'/'.join(c)}: {len(ms)} sample(s); ranges over {rg}; outline "
              f"{len(o.points_mm)} points, {len(o.holes_mm)} hole(s), symmetry {o.symmetry}"
              f"{', mirror symmetric' if o.mirror_symmetric else ''}")
    written = write_scenario(taught, args.out, args.cell, cell_spec,
                             len(train) + len(folders))
    for f in written:
        print(f"wrote {f}")
    # the written file, read back as any scenario is: what `feeder check` and the cell get
    _, _, locator = scenario_locator(args.out)
    if taught.recipe.golden_image and len(written) > 1:
        locator.set_golden(read_image(written[1]))
    if not test:
        return 0
    classes = ["/".join(c) for c in taught.samples]
    names = ", ".join(s.name for s in test)
    print(f"\nheld out {len(test)} of {len(labelled)} image(s): {names}")
    sc = score_finds(test, lambda s: [(f"{d.part}/{d.pose}", d.u_px, d.v_px)
                                      for d in locator.locate(s.image).parts], classes)
    for line in sc.table():
        print(line)
    base = score_finds(test, PlainBaseline(train).finds, classes)
    print(f"\nplain OpenCV (Otsu, contours, nearest class by area) on the same images: "
          f"F1 {base.f1:.3f}")
    print(f"taught recipe: F1 {sc.f1:.3f}")
    return 0


def _f1(path: str, written: list[str], samples: list[Sample], classes: list[str]) -> float:
    """The F1 of the scenario at ``path`` on labelled ``samples``, found by the locator
    the cell builds for it (as the held-out images are scored)."""
    _, _, locator = scenario_locator(path)
    if locator.recipe.golden_image and len(written) > 1:
        locator.set_golden(read_image(written[1]))
    return score_finds(samples, lambda s: [(f"{d.part}/{d.pose}", d.u_px, d.v_px)
                                           for d in locator.locate(s.image).parts],
                       classes).f1


def _choose_split(taught: Taught, train: list[Sample], cell: str, cell_spec: CellSpec
                  ) -> Taught:
    """The taught scenario with ``split_touching`` on if, on the teaching images, it finds
    the labelled parts at least as well as without: it only cuts blobs no class takes and
    keeps the pieces only when each is a part, so where it costs nothing there it can
    only save the parts that touch in other frames. Both are scored by the locator the
    cell would build from the written file."""
    classes = ["/".join(c) for c in taught.samples]
    f1 = []
    with tempfile.TemporaryDirectory() as tmp:
        for split in (False, True):
            t = replace(taught, recipe=replace(taught.recipe, split_touching=split))
            path = str(Path(tmp) / f"split_{int(split)}.yaml")
            written = write_scenario(t, path, cell, cell_spec, len(train))
            f1.append(_f1(path, written, train, classes))
    split = f1[1] >= f1[0]
    return replace(taught, recipe=replace(taught.recipe, split_touching=split),
                   split=(f1[0], f1[1]))



