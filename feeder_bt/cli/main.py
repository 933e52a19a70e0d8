"""``feeder``: the command line. Every error is one line and a non-zero exit, never a
traceback (set FEEDER_DEBUG=1 to see one)."""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
from pathlib import Path

from feeder_bt.analysis.summary import summary
from feeder_bt.cli.argtypes import expect_kind, positive
from feeder_bt.core.errors import ConfigError, FeederError, UsageError

# feeder_bt/cli/<module>.py, each with add_parser(subparsers) setting a `handler`
TOOLS = ("report_cmd", "calibrate", "locate_cmd", "render_cmd", "suggest", "emulate_cmd",
         "users_cmd", "commission", "tune", "replay_cmd", "teach_cmd", "twin_cmd")


#: ``feeder run``'s exit code when the simulated cell lost or duplicated a part (a bug in
#: the world or the trees, never the operator's doing): docs/faults.md
EXIT_ACCOUNTING = 4
#: ``feeder run``'s exit code when it placed nothing although parts came, or fewer parts/min
#: than ``--min-ppm`` asks: a CI job must tell such a run from a good one (docs/faults.md)
EXIT_FED_TOO_LITTLE = 5
NOTHING_FED_S = 60.0     # feeding time after which placing nothing fails a run



class _Parser(argparse.ArgumentParser):
    """One line for a usage mistake, like every other error (``feeder X --help`` for more),
    with a "did you mean" for a misspelt option, sub-command or choice."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: {message}{_did_you_mean(self, message)} "
                     f"(see {self.prog} --help)\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        """Unknown options are reported by the sub-command that was given them, so the
        suggestion comes from that sub-command's options."""
        ns, extras = super().parse_known_args(args, namespace)
        unknown = [a for a in extras if a.startswith("-")]
        sub = _subparser(self, getattr(ns, "command", None))
        if unknown and sub is not None and sub is not self:
            sub.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns, extras


def _subparser(parser: argparse.ArgumentParser, name: str | None
               ) -> argparse.ArgumentParser | None:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction) and name is not None:
            return action.choices.get(name)
    return None


def _did_you_mean(parser: argparse.ArgumentParser, message: str) -> str:
    """' (did you mean --fast?)' for an unknown option or choice close to a known one."""
    import difflib
    import re

    m = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
    if m:
        word, known = m.group(1), re.findall(r"'([^']*)'", m.group(2))
    else:
        m = re.search(r"unrecognized arguments: (\S+)", message)
        if not m or not m.group(1).startswith("-"):
            return ""
        word = m.group(1).split("=")[0]
        known = [o for a in parser._actions for o in a.option_strings if o.startswith("--")]
    close = difflib.get_close_matches(word, known, n=1, cutoff=0.6)
    return f" (did you mean {close[0]}?)" if close else ""


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="feeder", description="feeder_bt: a behaviour-tree cell controller for "
                "vision-based flexible parts feeders, with a simulated cell. Errors are one line; "
                "set FEEDER_DEBUG=1 for a traceback.")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND",
                           parser_class=_Parser)

    r = sub.add_parser("run", help="feed parts: the main job (simulated cell by default)")
    r.add_argument("scenario", help="scenario YAML, e.g. scenarios/lenses.yaml")
    r.add_argument("--cell", help="cell description YAML (default: the scenario's `cell:`)")
    r.add_argument("--duration", type=positive, default=None,
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
    from feeder_bt.app.run import add_db_options, add_ui_options
    add_db_options(r)
    r.add_argument("--min-ppm", type=float, metavar="PPM",
                   help=f"exit {EXIT_FED_TOO_LITTLE} when the run fed fewer parts/min than "
                        "this (a run that places nothing while parts came always does)")
    r.add_argument("--faults", metavar="PLAN.yaml",
                   help="simulated cell: inject the faults of a plan (docs/faults.md)")
    r.add_argument("--supply", metavar="PLAN.yaml",
                   help="simulated cell: bring parts and change conditions as a supply plan "
                        "says (docs/supply.md)")
    r.add_argument("--overlay", metavar="OVERLAY.yaml",
                   help="a partial scenario merged over SCENARIO before it is checked, e.g. "
                        "the settings `feeder tune --out` found")
    r.add_argument("--world", metavar="WORLD.yaml",
                   help="simulated cell: the cell's truth (physical and sim: figures laid "
                        "over the cell file, e.g. a twin from `feeder twin fit`); the "
                        "controller still reads only the cell file (docs/simulator.md)")
    add_ui_options(r)
    from feeder_bt.app.run import add_plant_options
    add_plant_options(r)

    t = sub.add_parser("tree", help="draw the feeding trees of a scenario")
    t.add_argument("scenario", nargs="?")
    t.add_argument("--format", default="unicode",
                   choices=["ascii", "unicode", "dot", "svg", "png"])
    t.add_argument("-o", "--output", help="write to this file instead of standard output")
    t.add_argument("--part", default="feeding", choices=["feeding", "setup", "cleanup"],
                   help="which tree (default: the four feeding trees)")
    t.add_argument("--legend", action="store_true",
                   help="print only what the node-kind glyphs (/_/ {o} {-} -^- -->) mean")

    c = sub.add_parser("check", help="validate scenarios, cell descriptions, fault and supply "
                       "plans "
                       "(each file's kind is told by its keys)")
    c.add_argument("files", nargs="+")
    c.add_argument("--images", metavar="DIR", help="also run each scenario's recipe on the "
                   "images in DIR (golden.png there: the golden image) and report the finds")

    from feeder_bt.config.schema import KINDS
    s = sub.add_parser("schema", help="print the JSON Schema of a file kind, for an editor "
                       "that checks YAML as you type (docs/getting-started.md), or of "
                       "the run report (--report), the JSON contract for CI")
    s.add_argument("kind", choices=[*KINDS, "world", "report"])
    s.add_argument("-o", "--output", help="write to this file instead of standard output")

    r.set_defaults(handler=cmd_run)
    t.set_defaults(handler=cmd_tree)
    c.set_defaults(handler=cmd_check)
    s.set_defaults(handler=cmd_schema)
    for tool in TOOLS:                  # each tool module adds its own sub-command
        importlib.import_module(f"feeder_bt.cli.{tool}").add_parser(sub)
    return p


def _check_run_args(args: argparse.Namespace) -> None:
    """Options that do not go together, and files of the wrong kind: one line, exit 2."""
    if args.fast and args.hal != "sim":
        raise UsageError("--fast needs the simulated cell (--hal sim): real hardware runs "
                         "in real time")
    if args.ui and args.fast:
        raise UsageError("--ui serves operators in real time: drop --fast")
    for path, kind, how in ((args.scenario, "scenario", ""),
                            (args.cell, "cell", "--cell"),
                            (args.faults, "faults", "--faults"),
                            (args.supply, "supply", "--supply")):
        if path is not None:
            expect_kind(path, kind, how)


def cmd_run(args: argparse.Namespace) -> int:
    from feeder_bt.app.run import RunOptions, plant_options, run_job
    _check_run_args(args)
    report = run_job(RunOptions(scenario=args.scenario, cell=args.cell, duration=args.duration,
                                fast=args.fast, seed=args.seed, report=args.report,
                                hal=args.hal, view=args.view, skip_idle=args.skip_idle,
                                db=args.db, ui=args.ui, users=args.users, start=args.start,
                                faults=args.faults, supply=args.supply,
                                plant=plant_options(args), overlay=args.overlay,
                                world=args.world))
    print(summary(report))
    p = report["parts"]
    nm = report["vision"].get("no_match") or {}
    if nm.get("alarms"):
        from feeder_bt.vision.watch import reasons_line, short
        why = reasons_line(nm.get("reasons") or {}, 60)
        print(short(f"WARNING: for up to {nm['longest_s']:.0f} s frames showed blobs but no "
                    f"part: {short(nm['example'], 60)} (blobs: {why}; see the "
                    f"vision_no_match events)", 200),
              file=sys.stderr)
    problems = p.get("accounting") or []
    if p.get("outcomes"):               # the world and the cell disagree on placements
        print(f"ACCOUNTING: placements the world and the cell do not agree on: "
              f"{p['outcomes']}", file=sys.stderr)
        return EXIT_ACCOUNTING
    if problems:
        for prob in problems[:10]:
            where = prob.get("last_place") or " and ".join(prob.get("places", []))
            print(f"ACCOUNTING: part {prob['id']} ({prob['type']}) {prob['kind']}: "
                  f"{where} at t={prob['t']:g} s", file=sys.stderr)
        return EXIT_ACCOUNTING
    if report["fault"]:
        print(f"FAULT: {report['fault']}", file=sys.stderr)
        return 3
    too_little = fed_too_little(report, args.min_ppm)
    if too_little:
        print(f"FED TOO LITTLE: {too_little}", file=sys.stderr)
        return EXIT_FED_TOO_LITTLE
    if args.report:
        print(f"report: {args.report}")
    return 0


def fed_too_little(report: dict, min_ppm: float | None) -> str | None:
    """Why the run fed too little to pass for a good one, or None: nothing placed while
    parts came (named by the commonest reason the recipe gave), or under ``min_ppm``."""
    p = report["parts"]
    placed = sum(p["retrieved"].values())
    came = p["located"] + p["located_unpickable"] + (report["vision"].get("no_match") or {}
                                                      ).get("frames_no_match", 0)
    # after a minute of feeding: a short run whose first parts have not yet reached a robot
    # (or whose robots come later, outside it) is not a failure
    if placed == 0 and came and report["feed_seconds"] >= NOTHING_FED_S:
        nm = report["vision"].get("no_match") or {}
        reasons = nm.get("reasons") or {}
        why = (f"the commonest rejection: {max(reasons, key=reasons.get)} "
               f"({reasons[max(reasons, key=reasons.get)]} blobs)" if reasons else
               f"{p['located']} located, {p['missed']} picks missed, "
               f"{p['too_far']} too far")
        return f"no part placed in {report['feed_seconds']:.0f} s although parts came; {why}"
    if min_ppm is not None and report["parts_per_minute"] < min_ppm:
        return (f"{report['parts_per_minute']:.1f} parts/min, under --min-ppm {min_ppm:g}")
    return None


def cmd_tree(args: argparse.Namespace) -> int:
    from feeder_bt.app.treeview import render_tree
    from feeder_bt.app.view import LEGEND
    if args.legend:
        print("\n".join(LEGEND))
        return 0
    if args.scenario is None:
        raise FeederError("tree: give a scenario (or --legend)")
    out = render_tree(args.scenario, args.format, args.part)
    if args.format in ("ascii", "unicode") and not args.output:
        out = f"{out.rstrip()}\n\n" + "\n".join(LEGEND)
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)     # out/ (README)
        Path(args.output).write_bytes(out if isinstance(out, bytes) else out.encode())
        print(f"wrote {args.output}")
    elif isinstance(out, bytes):
        raise FeederError(f"--format {args.format} is binary: give -o FILE")
    else:
        print(out)
    return 0


def cmd_check(args: argparse.Namespace) -> int:
    """Each file is read as the kind its keys say. A good file is one line on stdout; a bad
    one is every problem the loader finds in it, one line each on stderr in file order (the
    first says which kind the file was read as), then a count on stdout."""
    from feeder_bt.config import load_scenario
    from feeder_bt.config.files import check_file
    from feeder_bt.config.schema import describe, file_kind
    from feeder_bt.trees.leaves import leaf_problems
    bad = found = 0
    for path in args.files:
        kind, told, problems = check_file(path)   # told None: not a mapping of keys
        if not problems and kind == "scenario":   # its leaf classes, as a run would load them
            problems = leaf_problems(load_scenario(path)[0])
        if not problems:
            print(f"ok: {path} ({describe(kind)})")
            continue
        bad += 1
        found += len(problems)
        lines = ConfigError.of(problems).lines()
        # the kind is said on the file's own first line (a scenario's cell names its own)
        own = next((i for i, e in enumerate(problems[:len(lines)])
                    if e.file and Path(e.file) == Path(path)), None)
        how = "" if told else ": no key tells its kind"
        if own is None:
            lines[0] += f" (in the cell of {path}, {describe(kind)})"
        else:
            lines[own] += f" (read as {describe(kind)}{how})"
        for line in lines:
            print(line, file=sys.stderr)
    if bad:
        print(f"{found} problem{'s' if found > 1 else ''} in {bad} of {len(args.files)} "
              f"file{'s' if len(args.files) > 1 else ''}")
    if bad or not args.images:
        return 2 if bad else 0
    from feeder_bt.cli.check_images import check_images
    scenarios = [f for f in args.files if (file_kind(f) or "scenario") == "scenario"]
    if not scenarios:
        raise UsageError("--images runs a scenario's recipe: give a scenario file")
    return max(check_images(f, args.images) for f in scenarios)


def cmd_schema(args: argparse.Namespace) -> int:
    from feeder_bt.analysis.run_report import report_schema
    from feeder_bt.config.schema import schema
    from feeder_bt.config.world import world_schema
    doc = (report_schema() if args.kind == "report" else world_schema()
           if args.kind == "world" else schema(args.kind))
    text = json.dumps(doc, indent=2) + "\n"
    if args.output:
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)     # out/ (README)
        Path(args.output).write_text(text)
        print(f"wrote {args.output}")
    else:
        sys.stdout.write(text)
    return 0


def _interrupted(e: BaseException | None) -> bool:
    """Whether a Ctrl-C is somewhere in an exception's chain."""
    seen = 0
    while e is not None and seen < 20:
        if isinstance(e, KeyboardInterrupt):
            return True
        e, seen = e.__cause__ or e.__context__, seen + 1
    return False


def main(argv: list[str] | None = None) -> int:
    """The `feeder` command. Ctrl-C at any time, even while the first imports run (the
    parsers import every tool), ends with one line and 130, never a traceback."""
    try:
        args = build_parser().parse_args(argv)
        return args.handler(args)
    except FeederError as e:
        if os.environ.get("FEEDER_DEBUG"):
            raise
        lines = e.lines() if isinstance(e, ConfigError) else [str(e)]
        for line in lines:                  # every problem of a file, one line each
            print(f"feeder: {line}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("feeder: interrupted", file=sys.stderr)
        return 130
    except ImportError as e:               # numpy turns a Ctrl-C in its import into this
        if not _interrupted(e):
            raise
        print("feeder: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 1


if __name__ == "__main__":
    sys.exit(main())
