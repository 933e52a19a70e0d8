"""``feeder locate``: run a scenario's recipe on image files, as the cell would on a frame.

For tuning a recipe on recorded or rendered images without a cell: the table shows what was
found and why blobs were rejected (and, for an image with no part, why: no foreground
at all — with a hint when the other ``vision.foreground`` would find the parts — or the
rejects grouped by reason); ``--annotate`` draws it (contours, centroids, orientation
arrows, rejects with their reason); ``--json`` is for scripts and tests.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

from feeder_bt.cli.inputs import check_size, load_golden, scenario_locator
from feeder_bt.core.images import read_image, write_image
from feeder_bt.vision.diagnose import why_nothing
from feeder_bt.vision.locator import Detection

#: Features shown in the table (all are in the JSON).
TABLE_FEATURES = ("area_mm2", "circularity", "aspect", "holes")


def add_parser(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = subparsers.add_parser("locate", help="run a scenario's vision recipe on image files")
    p.add_argument("scenario", help="scenario YAML whose recipe and cell calibration to use")
    p.add_argument("images", nargs="+", metavar="IMAGE", help="PNG, JPG or BMP files")
    p.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    p.add_argument("--annotate", metavar="OUTDIR",
                   help="write IMAGE_annotated.png for each image into this folder")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--golden", metavar="IMAGE",
                   help="the empty, lit belt, for recipes with golden-image subtraction")
    p.set_defaults(handler=cmd_locate)
    return p


def cmd_locate(args: argparse.Namespace) -> int:
    """Locate parts in each image; 0 even if nothing is found (that is a result)."""
    _, _, locator = scenario_locator(args.scenario, args.cell)
    golden = load_golden(locator, args.golden, "feeder locate")
    images = [(path, read_image(path)) for path in args.images]   # all errors before output
    for path, img in images:
        check_size(path, img, golden)
    out: list[dict[str, Any]] = []
    for path, img in images:
        result = locator.locate(img, all_features=True)   # the table shows every feature
        row = {"image": path, "ms": round(result.ms, 3),
               "parts": [_det_dict(d) for d in result.parts],
               "rejected": [_det_dict(d) for d in result.rejected],
               "why": why_nothing(locator, img, result, golden)}
        if args.annotate:
            dest = Path(args.annotate) / f"{Path(path).stem}_annotated.png"
            write_image(dest, locator.annotate(img, result))
            row["annotated"] = str(dest)
        out.append(row)
        if not args.json:
            print(format_table(row, tuple(locator.recipe.rulers)))
    if args.json:
        json.dump(out, sys.stdout, indent=1)
        print()
    return 0


def _det_dict(d: Detection) -> dict[str, Any]:
    row = asdict(d)
    for k in ("x_mm", "y_mm", "angle_deg", "u_px", "v_px"):
        row[k] = round(row[k], 3)
    row["features"] = {k: round(v, 5) for k, v in d.features.items()}
    return row


def format_table(row: dict[str, Any], rulers: tuple[str, ...] = ()) -> str:
    """One image's result as a readable table: parts first, then rejected blobs and why;
    the recipe's ``rulers`` after the features."""
    shown = TABLE_FEATURES + rulers
    lines = [f"{row['image']}: {len(row['parts'])} part(s), {len(row['rejected'])} "
             f"rejected, {row['ms']:.1f} ms"]
    head = (f"  {'part':<12} {'pose':<10} {'pick':<4} {'u_px':>7} {'v_px':>7} {'x_mm':>8} "
            f"{'y_mm':>8} {'angle':>7} " + " ".join(f"{f:>11}" for f in shown))
    if row["parts"] or row["rejected"]:
        lines.append(head)
    for d in row["parts"] + row["rejected"]:
        name = d["part"] or "-"
        pose = d["pose"] or "-"
        pick = "yes" if d["pickable"] else "no"
        feats = " ".join(f"{d['features'].get(f, float('nan')):>11.3f}" for f in shown)
        line = (f"  {name:<12} {pose:<10} {pick:<4} {d['u_px']:>7.1f} {d['v_px']:>7.1f} "
                f"{d['x_mm']:>8.1f} {d['y_mm']:>8.1f} {d['angle_deg']:>7.1f} {feats}")
        if d["reason"]:
            line += f"  rejected: {d['reason']}"
        lines.append(line)
    lines += [f"  why no part: {line}" for line in row.get("why", [])]
    if "annotated" in row:
        lines.append(f"  annotated: {row['annotated']}")
    return "\n".join(lines)
