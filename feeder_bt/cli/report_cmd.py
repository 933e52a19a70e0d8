"""``feeder report FILE.db``: what the event log says about past runs — a summary table,
``--json`` for scripts, ``--plot`` for speed, queue and parts/min against time."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from feeder_bt.policy.kits import describe_kits
from feeder_bt.records.eventlog import ACCESS_KINDS, EventLogError, open_readonly
from feeder_bt.records.runs_db import run_ids, summary

COLUMNS = ("run", "scenario", "seed", "state", "duration_s", "parts/min", "retrieved",
           "located", "missed", "lost", "misoriented", "scrapped", "faults", "misses")


def add_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Register ``report`` on the ``feeder`` sub-command parsers."""
    p = subparsers.add_parser("report", help="summarise and plot runs from the event log")
    p.add_argument("db", metavar="FILE.db", nargs="?",
                   help="event log written by `feeder run --db`")
    p.add_argument("--study", metavar="FILE.db",
                   help="instead: the searches `feeder tune --study` kept there (--plot: "
                        "parts/min per trial and parameter importance)")
    which = p.add_mutually_exclusive_group()
    which.add_argument("--run", type=int, metavar="ID", help="only this run")
    which.add_argument("--last", action="store_true", help="only the latest run")
    p.add_argument("--plot", metavar="OUT.png",
                   help="draw speed, queue and parts/min against time (the chosen run, "
                        "else the latest)")
    p.add_argument("--json", action="store_true", help="print the summaries as JSON")
    p.add_argument("--access", action="store_true",
                   help="list every operator access event (failed logins, lock-outs, "
                        "refusals, control released), not only their counts")
    p.set_defaults(handler=cmd_report)
    return p


def cmd_report(args: argparse.Namespace) -> int:
    """Print the summaries; write the plot if asked. Errors are EventLogError (exit 2)."""
    if args.study or args.db is None:
        if args.db is not None or args.study is None:
            raise EventLogError("give an event log FILE.db or --study FILE.db (one of them)")
        from feeder_bt.tuning.report import report_study
        return report_study(args.study, args.plot)
    conn = open_readonly(args.db)
    try:
        ids = run_ids(conn, args.run, args.last)
        rows = [summary(conn, i) for i in ids]
        for row in rows:
            row["access"] = access_counts(conn, row["run"])
        if args.json:
            print(json.dumps(rows if len(rows) > 1 else rows[0], indent=2))
        else:
            print(format_table(rows))
            for row in rows:                  # faults, misses, alarms: vocabulary.py
                if row["story"] != ["faults 0"]:      # a clean run: the table says it all
                    print(f"run {row['run']}: " + "; ".join(row["story"]))
                if row.get("kits"):
                    print(kits_line(row))
            for line in access_lines(conn, rows, getattr(args, "access", False)):
                print(line)
        if args.plot:
            write_plot(conn, ids[-1], args.plot)
            print(f"plot: {args.plot} (run {ids[-1]})")
    finally:
        conn.close()
    return 0


def kits_line(row: dict[str, Any]) -> str:
    """A kit run's kits as its summary said them, and minute by minute (or each few
    minutes, ``runs_db.kits_by_minute``)."""
    k = row["kits"]
    line = f"run {row['run']} {describe_kits(k)}"
    if not k.get("by_bin"):
        return line
    mins = round(k["bin_s"] / 60.0)
    per = "minute" if mins == 1 else f"{mins} minutes"
    last = k["last_bin_s"]
    part = f" (the last over {last:g} s)" if last < k["bin_s"] - 1e-3 else ""
    return f"{line}; by {per} of feeding: {' '.join(map(str, k['by_bin']))}{part}"


def access_counts(conn: Any, run_id: int) -> dict[str, int]:
    """How many of each operator access event a run recorded."""
    kinds = tuple(ACCESS_KINDS)
    marks = ",".join("?" * len(kinds))
    try:
        rows = conn.execute(f"SELECT kind, count(*), sum(coalesce(json_extract(data, "
                            f"'$.count'), 1)) FROM events WHERE run_id=? AND kind IN "
                            f"({marks}) GROUP BY kind", (run_id, *kinds)).fetchall()
    except Exception as e:                    # sqlite3.Error: a damaged log
        raise EventLogError(f"run {run_id}: damaged record ({e})") from None
    return {kind: int(total if kind == "access_suppressed" else n)
            for kind, n, total in sorted(rows, key=lambda r: kinds.index(r[0]))}


def access_lines(conn: Any, rows: list[dict[str, Any]], every: bool) -> list[str]:
    """Below the table: per run, its access events counted (and, with ``every``, listed)."""
    out: list[str] = []
    for row in rows:
        counts = row["access"]
        if not counts:
            continue
        words = ", ".join(f"{n} {ACCESS_KINDS[k]}" for k, n in counts.items())
        out.append(f"run {row['run']} operator access: {words}")
        if every:
            for t, kind, data in conn.execute(
                    "SELECT t, kind, data FROM events WHERE run_id=? AND kind IN "
                    f"({','.join('?' * len(ACCESS_KINDS))}) ORDER BY rowid",
                    (row["run"], *ACCESS_KINDS)):
                fields = json.loads(data or "{}")
                who = fields.pop("user", "-")
                rest = " ".join(f"{k}={v}" for k, v in fields.items())
                out.append(f"  {t:10.2f}  {kind:16}  {who}  {rest}".rstrip())
    return out


def write_plot(conn: Any, run_id: int, out: str | Path) -> None:
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise EventLogError("--plot needs matplotlib: pip install 'matplotlib>=3.7'") from None
    from feeder_bt.cli.plots import plot_run
    fig = plot_run(conn, run_id)
    try:
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        # the title in the PNG's text too: docs/build.py checks a quoted plot by it
        meta = {"Title": fig.get_suptitle()} if str(out).lower().endswith(".png") else None
        fig.savefig(out, dpi=100, metadata=meta)
    except (OSError, ValueError) as e:
        raise EventLogError(f"cannot write {out}: {e}") from None


def _cell(key: str, row: dict[str, Any]) -> str:
    value = row.get({"parts/min": "parts_per_minute"}.get(key, key))
    if value is None:
        return "-"
    if isinstance(value, dict) and key in ("faults", "misses"):   # by kind: the line below
        return str(sum(value.values()))
    if isinstance(value, dict):
        return ", ".join(f"{k} {v}" for k, v in value.items()) or "0"
    if isinstance(value, float):
        return f"{value:.1f}"
    return str(value)


def format_table(rows: list[dict[str, Any]]) -> str:
    """Plain aligned columns; numbers right-aligned."""
    cells = [COLUMNS] + [tuple(_cell(k, r) for k in COLUMNS) for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(COLUMNS))]
    right = {"run", "seed", "duration_s", "parts/min", "located", "missed", "lost",
             "misoriented", "scrapped", "faults", "misses"}
    return "\n".join("  ".join(c.rjust(w) if k in right else c.ljust(w)
                               for k, c, w in zip(COLUMNS, line, widths, strict=True)).rstrip()
                     for line in cells)

