"""``feeder``: the command line. Every error is one line and a non-zero exit, never a
traceback (set FEEDER_DEBUG=1 to see one)."""

from __future__ import annotations

import argparse
import importlib
import os
import sys
from pathlib import Path

from .errors import FeederError

# feeder_bt/tools/<module>.py, each with add_parser(subparsers) setting a `handler`
TOOLS = ("report_cmd", "calibrate", "locate_cmd", "render_cmd", "suggest", "emulate_cmd",
         "users_cmd")


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


class _Parser(argparse.ArgumentParser):
    """One line for a usage mistake, like every other error (``feeder X --help`` for more)."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="feeder", description="feeder_bt: a behaviour-tree cell controller for "
                "vision-based flexible parts feeders, with a simulated cell. Errors are one line; "
                "set FEEDER_DEBUG=1 for a traceback.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND",
                           parser_class=_Parser)

    r = sub.add_parser("run", help="feed parts: the main job (simulated cell by default)")
    r.add_argument("scenario", help="scenario YAML, e.g. scenarios/lenses.yaml")
    r.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    r.add_argument("--duration", type=_positive, default=None,
                   help="seconds of feeding (virtual seconds on the simulated cell); default 60 "
                        "(with --ui: until Ctrl-C)")
    r.add_argument("--fast", action="store_true",
                   help="simulated cell only: run virtual time as fast as possible")
    r.add_argument("--seed", type=int, default=1, help="random seed of the simulated cell")
    r.add_argument("--report", metavar="FILE.json", help="write the run report here")
    r.add_argument("--hal", default="sim", choices=["sim", "emulated", "real"],
                   help="which hardware layer: sim (default), emulated, real")
    r.add_argument("--view", default="unicode", choices=["unicode", "ascii", "none"],
                   help="live tree view in real-time runs (default unicode)")
    r.add_argument("--no-skip", dest="skip_idle", action="store_false",
                   help="fast runs: tick every tick even when nothing can change")
    from .run import add_db_options, add_ui_options
    add_db_options(r)
    r.add_argument("--faults", metavar="PLAN.yaml",
                   help="simulated cell: inject the faults of a plan (docs/faults.md)")
    add_ui_options(r)

    t = sub.add_parser("tree", help="draw the feeding trees of a scenario")
    t.add_argument("scenario")
    t.add_argument("--format", default="unicode",
                   choices=["ascii", "unicode", "dot", "svg", "png"])
    t.add_argument("-o", "--output", help="write to this file instead of standard output")
    t.add_argument("--part", default="feeding", choices=["feeding", "setup", "cleanup"],
                   help="which tree (default: the four feeding trees)")

    c = sub.add_parser("check", help="validate scenario and cell YAML files")
    c.add_argument("files", nargs="+")

    r.set_defaults(handler=cmd_run)
    t.set_defaults(handler=cmd_tree)
    c.set_defaults(handler=cmd_check)
    for tool in TOOLS:                  # each tool module adds its own sub-command
        importlib.import_module(f".tools.{tool}", __package__).add_parser(sub)
    return p


def cmd_run(args: argparse.Namespace) -> int:
    from .run import RunOptions, run_job
    if args.fast and args.hal != "sim":
        raise FeederError("--fast needs the simulated cell (--hal sim): real hardware runs "
                          "in real time")
    report = run_job(RunOptions(scenario=args.scenario, cell=args.cell, duration=args.duration,
                                fast=args.fast, seed=args.seed, report=args.report,
                                hal=args.hal, view=args.view, skip_idle=args.skip_idle,
                                db=args.db, ui=args.ui, users=args.users, start=args.start,
                                faults=args.faults))
    print(summary(report))
    if report["fault"]:
        print(f"FAULT: {report['fault']}", file=sys.stderr)
        return 3
    if args.report:
        print(f"report: {args.report}")
    return 0


def summary(report: dict) -> str:
    """The run's summary, two lines that fit 80 columns; its parts/min is the report's and
    the live view's last."""
    p = report["parts"]
    how = " (interrupted by Ctrl-C)" if report.get("interrupted") else ""
    kinds = ", ".join(f"{k} {v}" for k, v in p["retrieved"].items())
    return (f"{report['scenario']}: {report['state']}{how} after {report['feed_seconds']:.0f} s"
            f", {report['parts_per_minute']:.1f} parts/min ({report['wall_seconds']:.1f} s "
            f"wall)\n  retrieved {sum(p['retrieved'].values())} ({kinds}), located "
            f"{p['located']}, missed {p['missed']}, lost {p['lost']}")


def cmd_tree(args: argparse.Namespace) -> int:
    from .treeview import render_tree
    out = render_tree(args.scenario, args.format, args.part)
    if args.output:
        Path(args.output).write_bytes(out if isinstance(out, bytes) else out.encode())
        print(f"wrote {args.output}")
    elif isinstance(out, bytes):
        raise FeederError(f"--format {args.format} is binary: give -o FILE")
    else:
        print(out)
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    from .scenario import check_files
    errors = check_files(args.files)
    for line in errors:
        print(line, file=sys.stderr)
    if not errors:
        print(f"ok: {len(args.files)} file(s)")
    return 2 if errors else 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.handler(args)
    except FeederError as e:
        if os.environ.get("FEEDER_DEBUG"):
            raise
        print(f"feeder: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("feeder: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1


if __name__ == "__main__":
    sys.exit(main())
