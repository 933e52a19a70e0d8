"""Time whole fast runs of the shipped scenarios and write what they report as JSON.

    python benchmarks/run_bench.py [--duration 3600] [--seeds 1] [--repeats 1] [--out PATH]
        [--before REV [--passes N]] [--components]

Simulator speed, side by side with the code before (lenses with vision in the loop, one
simulated hour, >= 300x real time)::

    python benchmarks/run_bench.py --scenarios lenses --seeds 3 --before c28a170 \\
        --passes 2 --components --out benchmarks/results/simspeed.json

Each (scenario, seed) runs ``--repeats`` times in a row; a fast run is deterministic, so
the repeats must report the same counts (checked), and only the time differs: the
simulated seconds per wall second are given per repeat and as min / median / max, with
the process CPU time (all threads) per simulated hour and the load average around the
runs, since the project's 2-core machine is shared and one run's speed says little on its
own (the simulated seconds per CPU second say more).

``--before REV`` also times the code at git revision REV: it is checked out in a temporary
worktree and this script runs it there (in a child process whose ``feeder_bt`` is that
checkout's), then this checkout, by turns for ``--passes`` passes; the JSON holds both, and
the counts of each (scenario, seed) must be the same in both (a speed change must not
change a result; reported, and exit 1 if not). ``--components`` adds one more run of
seed 1 per checkout with the thread CPU time of its parts (tree ticks, rendering, the
world's step, the locator, the end-of-run replay, the progress line; measured by wrapping
them, so that run is a little slower and is not one of the timed ones). Speed is measured
here, never in tests.
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
from side_by_side import git_rev  # noqa: E402, I001 - a sibling script's: one way to name a checkout

SCENARIOS = ("lenses", "squares", "lenses_and_squares")


def _code_root(argv: list[str]) -> Path:
    """The checkout whose ``feeder_bt`` is timed (``--code-root``, default this one)."""
    if "--code-root" in argv:
        return Path(argv[argv.index("--code-root") + 1]).resolve()
    return ROOT


def _counts(r: dict) -> tuple:
    """What must not change between repeats of one (scenario, seed), nor between checkouts."""
    p = r["parts"]
    return (json.dumps(p["retrieved"], sort_keys=True), p["located"], p["missed"], p["lost"],
            p["misoriented"], r["vision"]["frames"], r["tick"]["ticks"], r["tick"]["skipped"])


def _wrap_components(acc: collections.Counter) -> None:
    """Count each part's thread CPU time into ``acc`` (names found in the old code too)."""
    import feeder_bt.analysis.report as report_mod
    import feeder_bt.app.view as view_mod
    import feeder_bt.control.cell as cell_mod
    import feeder_bt.sim.render as render_mod
    import feeder_bt.sim.world as world_mod
    import feeder_bt.vision.locator as locator_mod

    def wrap(owner: object, name: str, key: str) -> None:
        fn = getattr(owner, name)

        @functools.wraps(fn)
        def timed(*a, **k):
            t = time.thread_time()
            try:
                return fn(*a, **k)
            finally:
                acc[key] += time.thread_time() - t
        setattr(owner, name, timed)

    wrap(cell_mod.Cell, "tick", "tree ticks")
    wrap(render_mod.Renderer, "render_px", "rendering")
    wrap(world_mod.World, "step", "world step")
    wrap(locator_mod.Locator, "locate", "locator")
    wrap(report_mod, "selection_bound", "end-of-run replay")
    wrap(view_mod.Progress, "update", "progress line")


def measure(args: argparse.Namespace) -> dict:
    """This process's runs (of the ``feeder_bt`` first on ``sys.path``)."""
    from feeder_bt.app.run import RunOptions, run_job
    try:        # the locator's kernels compiled (a fresh checkout's first run) before timing
        from feeder_bt.vision.jit import warm
    except ImportError:
        pass
    else:
        warm()
    rows = []
    load0 = os.getloadavg()
    for name in args.scenarios:
        for seed in range(1, args.seeds + 1):
            speeds, walls, cpus, first = [], [], [], None
            for _ in range(args.repeats):
                c0 = time.process_time()
                r = run_job(RunOptions(scenario=str(ROOT / "scenarios" / f"{name}.yaml"),
                                       duration=args.duration, fast=True, seed=seed,
                                       view="none"))
                cpus.append(round(time.process_time() - c0, 2))
                walls.append(r["wall_seconds"])
                speeds.append(round(r["sim_seconds"] / max(r["wall_seconds"], 1e-9), 1))
                if first is None:
                    first = r
                elif _counts(r) != _counts(first):
                    raise SystemExit(f"{name} seed {seed}: a repeat reported other counts "
                                     f"{_counts(r)} than the first {_counts(first)}")
                print(f"{name} seed {seed}: {r['parts_per_minute']:.3f}/min, lost "
                      f"{r['parts']['lost']}, {r['wall_seconds']:.1f} s wall "
                      f"({speeds[-1]:.0f}x), {cpus[-1]:.1f} s CPU", file=sys.stderr)
            r = first
            hours = r["sim_seconds"] / 3600.0
            rows.append({"scenario": name, "seed": seed, "sim_seconds": r["sim_seconds"],
                         "wall_seconds": statistics.median(walls), "wall_seconds_runs": walls,
                         "sim_per_wall": statistics.median(speeds),
                         "sim_per_wall_runs": speeds,
                         "sim_per_wall_min_max": [min(speeds), max(speeds)],
                         "cpu_seconds_runs": cpus,
                         "cpu_s_per_sim_hour": round(statistics.median(cpus) / hours, 2),
                         "sim_per_cpu": round(r["sim_seconds"] / statistics.median(cpus), 1),
                         "counts": list(_counts(r)),
                         "parts_per_minute": r["parts_per_minute"],
                         "retrieved": r["parts"]["retrieved"], "located": r["parts"]["located"],
                         "missed": r["parts"]["missed"], "lost": r["parts"]["lost"],
                         "misoriented": r["parts"]["misoriented"], "tick": r["tick"],
                         "vision": r["vision"],
                         "robot_bound_selection_ppm": r.get("robot_bound_selection_ppm")})
    out: dict = {"runs": rows,
                 "load_average_1_5_15": {"before": [round(x, 2) for x in load0],
                                         "after": [round(x, 2) for x in os.getloadavg()]}}
    if args.components:
        acc: collections.Counter = collections.Counter()
        _wrap_components(acc)
        name = args.scenarios[0]
        c0 = time.process_time()
        r = run_job(RunOptions(scenario=str(ROOT / "scenarios" / f"{name}.yaml"),
                               duration=args.duration, fast=True, seed=1, view="none"))
        cpu = time.process_time() - c0
        per_hour = 3600.0 / r["sim_seconds"]
        parts = {k: round(v * per_hour, 2) for k, v in acc.most_common()}
        parts["rest"] = round(cpu * per_hour - sum(parts.values()), 2)
        out["components"] = {"scenario": name, "seed": 1, "cpu_s_per_sim_hour":
                             round(cpu * per_hour, 2), "thread_cpu_s_per_sim_hour": parts,
                             "ticks": r["tick"]["ticks"]}
        print(f"components ({name} seed 1, CPU s per simulated hour): {parts}",
              file=sys.stderr)
    return out


def _child(code: Path, args: argparse.Namespace, out: Path) -> dict:
    """This script's ``measure`` in a child process timing the checkout ``code``."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--code-root", str(code),
           "--duration", str(args.duration), "--seeds", str(args.seeds),
           "--repeats", str(args.repeats), "--scenarios", *args.scenarios,
           "--out", str(out), "--child"]
    if args.components:
        cmd.append("--components")
    env = {**os.environ, "PYTHONPATH": str(code)}
    done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True)
    if done.returncode != 0:
        raise SystemExit(f"run_bench: the run in {code} failed: "
                         f"{(done.stderr.strip().splitlines() or ['no output'])[-1]}")
    for line in done.stderr.splitlines():
        if not line.lstrip().startswith(("10", "20", "30", "40", "50", "60", "70", "80",
                                         "90", "feeder: compiling")):
            print(f"  [{code.name}] {line}", file=sys.stderr)
    return json.loads(out.read_text())


def side_by_side(args: argparse.Namespace) -> dict:
    """The code at ``--before`` and this checkout, by turns; counts compared."""
    rev = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", args.before],
                         capture_output=True, text=True, check=True).stdout.strip()
    passes: list[dict] = []
    with tempfile.TemporaryDirectory(prefix="run-bench-before-") as tmp:
        before = Path(tmp) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(before),
                        rev], check=True, capture_output=True)
        try:
            for n in range(1, args.passes + 1):
                for code, tree in (("before", before), ("after", ROOT)):
                    print(f"pass {n}/{args.passes}: {code}", file=sys.stderr, flush=True)
                    report = _child(tree, args, Path(tmp) / f"{code}{n}.json")
                    passes.append({**report, "rev": report.get("code"), "code": code,
                                   "pass": n})
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force",
                            str(before)], capture_output=True)
    table = []
    same = True
    for name in args.scenarios:
        for seed in range(1, args.seeds + 1):
            row: dict = {"scenario": name, "seed": seed}
            for code in ("before", "after"):
                runs = [r for p in passes if p["code"] == code for r in p["runs"]
                        if r["scenario"] == name and r["seed"] == seed]
                row[code] = {
                    "parts_per_minute": runs[0]["parts_per_minute"],
                    "counts": runs[0]["counts"],
                    "sim_per_wall_runs": [s for r in runs for s in r["sim_per_wall_runs"]],
                    "sim_per_wall": statistics.median(s for r in runs
                                                      for s in r["sim_per_wall_runs"]),
                    "cpu_s_per_sim_hour": statistics.median(r["cpu_s_per_sim_hour"]
                                                            for r in runs),
                    "sim_per_cpu": statistics.median(r["sim_per_cpu"] for r in runs)}
            row["counts_same"] = row["before"]["counts"] == row["after"]["counts"]
            same &= row["counts_same"]
            table.append(row)
            b, a = row["before"], row["after"]
            print(f"{name} seed {seed}: before {b['parts_per_minute']:.3f}/min "
                  f"{b['sim_per_wall']:.0f}x ({b['cpu_s_per_sim_hour']:.1f} CPU s/h), after "
                  f"{a['parts_per_minute']:.3f}/min {a['sim_per_wall']:.0f}x "
                  f"({a['cpu_s_per_sim_hour']:.1f} CPU s/h); counts "
                  f"{'the same' if row['counts_same'] else 'DIFFER'}", file=sys.stderr)
    components = {p["code"]: p["components"] for p in passes if "components" in p}
    return {"side_by_side": {"before": rev, "after": git_rev(ROOT), "passes": args.passes,
                             "table": table, "counts_same": same, "components": components,
                             "runs": passes}}


def main(argv: list[str] | None = None) -> dict:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("--seeds", type=int, default=1, help="seeds 1..N per scenario")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each (scenario, seed)")
    ap.add_argument("--scenarios", nargs="*", default=list(SCENARIOS))
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "runs.json"))
    ap.add_argument("--before", metavar="REV", help="also time the code at this revision, "
                    "by turns with this checkout")
    ap.add_argument("--passes", type=int, default=1, help="with --before: passes of both")
    ap.add_argument("--components", action="store_true",
                    help="one more run of seed 1 with each part's CPU time")
    ap.add_argument("--code-root", help=argparse.SUPPRESS)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    sys.path.insert(0, str(_code_root(argv)))
    result = {"benchmark": "runs", "duration_s": args.duration, "repeats": args.repeats,
              "command": " ".join(["python", "benchmarks/run_bench.py", *[
                  a for a in argv if not a.startswith("--child")]]),
              "cpus": os.cpu_count(), "python": platform.python_version(),
              "machine": platform.machine()}
    if args.before:
        result.update(side_by_side(args))
    else:
        result["code"] = git_rev(_code_root(argv))
        result.update(measure(args))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2) + "\n")
    if args.before and not result["side_by_side"]["counts_same"]:
        raise SystemExit("run_bench: the counts differ between the two checkouts")
    return result


if __name__ == "__main__":
    main()
