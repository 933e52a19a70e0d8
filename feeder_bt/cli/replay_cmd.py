"""``feeder replay FILE.db``: the trees and the blackboard of a past run as they were at a
given time (``--at``, ``--before-fault``), as text or JSON; ``--ui`` serves the dashboard's
tree view with its timeline over the run (docs/operator-ui.md)."""

from __future__ import annotations

import argparse
import json
import sqlite3
import sys
from typing import Any

from feeder_bt.core.vocabulary import MISS_KINDS
from feeder_bt.records.eventlog import EventLogError, open_readonly
from feeder_bt.records.runs_db import run_ids
from feeder_bt.records.treelog import STATUS_NAMES, TraceView, TreeState, read_trace

MARK = {"invalid": "[-]", "running": "[*]", "success": "[✓]", "failure": "[✕]"}
SHAPE = {"sequence": "{-}", "selector": "{o}", "parallel": "/_/", "decorator": "-^-",
         "leaf": "-->"}


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``replay`` on the ``feeder`` sub-command parsers."""
    p = subparsers.add_parser("replay", help="the trees and blackboard of a past run at any "
                              "time (text, JSON, or the dashboard's timeline with --ui)")
    p.add_argument("db", metavar="FILE.db", help="event log written by `feeder run --db`")
    p.add_argument("--run", type=int, metavar="ID", help="which run (default: the latest)")
    when = p.add_mutually_exclusive_group()
    when.add_argument("--at", type=float, metavar="SECONDS",
                      help="the run's clock time (default: its end)")
    when.add_argument("--before-fault", type=float, nargs="?", const=1.0, metavar="SECONDS",
                      help="this long before the run's first fault (default 1 s)")
    p.add_argument("--tree", choices=["setup", "feeding", "cleanup"],
                   help="draw this tree (default: the one ticked at that time)")
    p.add_argument("--json", action="store_true", help="print the state as JSON")
    def bind(text: str) -> str:
        from feeder_bt.ui import parse_bind
        parse_bind(text)                 # a usage mistake: one line, exit 2
        return text

    p.add_argument("--ui", nargs="?", const="127.0.0.1:8080", type=bind, metavar="HOST:PORT",
                   help="serve the tree view with a timeline over the whole run "
                        "(default 127.0.0.1:8080; until Ctrl-C)")
    p.add_argument("--users", metavar="FILE",
                   help="with --ui: the users file viewers sign in with (default: the "
                        "dashboard's, ~/.config/feeder_bt/users.json)")
    p.set_defaults(handler=cmd_replay)
    return p


def faults(conn: sqlite3.Connection, run_id: int) -> tuple[list[tuple[float, str]], int]:
    """(time, message) of each fault (one that stopped or degraded the cell: a servo
    timeout, a lost link, an e-stop...), in order, and how many misses (retried grabs and
    picks, not faults: vocabulary.py) the run had besides."""
    out, misses = [], 0
    for t, d in conn.execute("SELECT t, data FROM events WHERE run_id=? AND kind='fault' "
                             "ORDER BY rowid", (run_id,)):
        data = json.loads(d or "{}")
        if data.get("kind") in MISS_KINDS:
            misses += 1
        else:
            out.append((t, data.get("message", "?")))
    return out, misses


def pick_time(conn: sqlite3.Connection, run_id: int, view: TraceView,
              at: float | None, before_fault: float | None) -> tuple[float, str]:
    """The time asked for, and a few words saying what it is."""
    t_first, t_last = view.span
    if before_fault is not None:
        found, misses = faults(conn, run_id)
        if not found:
            also = f" ({misses} miss{'es' * (misses != 1)}, each retried)" if misses else ""
            raise EventLogError(f"run {run_id} had no fault{also}: give --at SECONDS instead")
        tf, why = found[0]
        t = max(t_first, tf - before_fault)
        return t, f"{tf - t:g} s before the fault at {tf:.2f} s ({why})"
    if at is None:
        return t_last, "the end of the run"
    if not t_first <= at <= t_last:
        raise EventLogError(f"--at {at:g}: run {run_id} was recorded from {t_first:.2f} to "
                            f"{t_last:.2f} s")
    return at, f"{at:g} s"


def node_paths(view: TraceView) -> list[str]:
    """Each node's place as child indexes from its root ("feeding/0/2/1"): the same for a
    tree rebuilt at each start, and what tests compare with the live trees."""
    paths: list[str] = []
    count: dict[int, int] = {}
    for n in view.nodes:                          # ids are given parents first
        if n.parent < 0:
            paths.append(n.tree)
        else:
            i = count.get(n.parent, 0)
            count[n.parent] = i + 1
            paths.append(f"{paths[n.parent]}/{i}")
    return paths


def state_json(view: TraceView, state: TreeState, tree: str | None) -> dict[str, Any]:
    paths = node_paths(view)
    return {"t": state.t, "ticked": state.tree, "tree": tree,
            "nodes": [{"id": n.id, "path": paths[n.id], "name": n.name,
                       "kind": n.kind.split(":")[0],
                       "status": STATUS_NAMES[state.statuses[n.id]]}
                      for n in view.nodes if n.tree == tree],
            "blackboard": state.board}


def draw(view: TraceView, state: TreeState, tree: str | None) -> list[str]:
    """The tree as ``feeder tree`` draws it, with each node's status then."""
    kids: dict[int, list[int]] = {}
    roots = []
    for n in view.nodes:
        if n.tree != tree:
            continue
        (roots if n.parent < 0 else kids.setdefault(n.parent, [])).append(n.id)
    lines: list[str] = []

    def walk(nid: int, depth: int) -> None:
        n = view.nodes[nid]
        status = STATUS_NAMES[state.statuses[nid]]
        lines.append(f"{'    ' * depth}{SHAPE[n.kind.split(':')[0]]} {n.name} {MARK[status]}")
        for k in kids.get(nid, ()):
            walk(k, depth + 1)

    for r in roots:
        walk(r, 0)
    return lines


def cmd_replay(args: argparse.Namespace) -> int:
    conn = open_readonly(args.db)
    try:
        run_id = run_ids(conn, args.run, args.run is None)[-1]
        view = read_trace(conn, run_id)
        if not view.nodes:
            raise EventLogError(f"run {run_id} has no recorded trees (a run logged before "
                                "the trees' history was recorded)")
        if args.ui:
            from feeder_bt.ui.replay import serve_replay
            return serve_replay(args.db, run_id, args.ui, args.users)
        t, what = pick_time(conn, run_id, view, args.at, args.before_fault)
        state = view.at(t)
        tree = args.tree or state.tree or _last_tree(view, t)
        if args.json:
            print(json.dumps({"run": run_id, "when": what, **state_json(view, state, tree)},
                             indent=1))
            return 0
        ticked = f"the {state.tree} tree" if state.tree else "no tree ticked"
        if tree != state.tree:
            ticked += f"; drawn: the {tree} tree"
        print(f"run {run_id} at t = {t:.2f} s ({what}): {ticked}")
        for line in draw(view, state, tree):
            print(line)
        print("blackboard:")
        for k, v in state.board.items():
            print(f"  {k} = {v}")
    finally:
        conn.close()
    sys.stdout.flush()
    return 0


def _last_tree(view: TraceView, t: float) -> str:
    """Between trees (paused, stopped, after an e-stop): the feeding tree."""
    return "feeding" if any(n.tree == "feeding" for n in view.nodes) else view.nodes[0].tree
