"""``feeder twin fit RUN.db... --cell CELL.yaml --out TWIN.yaml``: a world file fitted from
a cell's event logs (``tuning/twin.py``), for ``feeder run --world TWIN.yaml``."""

from __future__ import annotations

import argparse
import sys
from typing import Any


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``twin`` (and its ``fit``) on the ``feeder`` sub-command parsers."""
    p = subparsers.add_parser("twin", help="fit a world file (a twin) from a cell's event "
                              "logs, for `feeder run --world`")
    sub = p.add_subparsers(dest="twin_cmd", required=True, metavar="fit")
    f = sub.add_parser("fit", help="fit the world's figures from event logs of a cell "
                       "(simulated or real), using only what a real cell records")
    f.add_argument("logs", nargs="+", metavar="RUN.db",
                   help="event logs written by `feeder run --db` (every run in each)")
    f.add_argument("--cell", required=True, metavar="CELL.yaml",
                   help="the cell file the logged runs' controller read")
    f.add_argument("--out", required=True, metavar="TWIN.yaml",
                   help="write the twin's world file here")
    f.add_argument("--scenario", metavar="SCENARIO.yaml",
                   help="the scenario the logged runs ran (default: the path the log names)")
    f.add_argument("--rounds", type=int, default=4, metavar="N",
                   help="rounds of simulated runs to match the logged counts (default 4)")
    f.set_defaults(handler=cmd_twin_fit)
    return p


def cmd_twin_fit(args: argparse.Namespace) -> int:
    from feeder_bt.config import load_cell
    from feeder_bt.tuning.twin import fit_twin
    cell = load_cell(args.cell)
    twin = fit_twin(args.logs, cell, rounds=max(1, args.rounds),
                    say=lambda s: print(s, file=sys.stderr), scenario=args.scenario)
    twin.write(args.out)
    print(f"twin of {args.cell} from {len(args.logs)} log(s):")
    for key, e in twin.estimates.items():
        if e.fixed:
            sd = f" ± {e.sd:.3g}" if e.sd is not None else ""
            print(f"  {key} = {e.value:.4g}{sd}  ({e.fixed_by})")
    for key, why in twin.notes()["not_fixed"].items():
        print(f"  {key}: not fixed: {why}")
    print(f"world: {args.out}\nuse: feeder run SCENARIO --fast --world {args.out}")
    return 0
