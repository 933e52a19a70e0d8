"""One benchmark run in two checkouts by turns: a change's effect measured against the same
machine's mood.

    python benchmarks/side_by_side.py --before DIR [--passes 5] --out RESULT.json \\
        -- benchmarks/vision_bench.py --scenarios squares --repeats 3

``DIR`` is the code before the change (``git worktree add DIR REV``, or ``git archive``
unpacked); this checkout is the code after. Each pass runs the benchmark script (the path
after ``--``, relative to a checkout, with its arguments and ``--out`` added) in ``DIR``,
then here, and keeps both JSON reports whole, so anything they hold can be compared. A
benchmark that imports ``feeder_bt`` from its own checkout (``vision_bench.py``,
``run_bench.py``: they put their checkout first on ``sys.path``) times that code. On a
shared machine one pair says little; read the passes together.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def git_rev(tree: Path) -> str:
    """The checkout's commit (and "+" if it has changes), or "?" outside git."""
    try:
        rev = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain",
                                "--untracked-files=no"],
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"
    return rev + ("+" if dirty else "")


def run_once(tree: Path, script: str, args: list[str], out: Path) -> dict:
    """The benchmark's report from one run in ``tree``; one line and exit 1 if it fails."""
    cmd = [sys.executable, str(tree / script), *args, "--out", str(out)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        last = (done.stderr.strip().splitlines() or ["no output"])[-1]
        raise SystemExit(f"side_by_side: {script} in {tree} failed: {last}")
    return json.loads(out.read_text())


def main(argv: list[str] | None = None) -> dict:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv:
        raise SystemExit("side_by_side: give the benchmark after --, e.g. -- "
                         "benchmarks/vision_bench.py --scenarios squares")
    cut = argv.index("--")
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", type=Path, required=True, help="checkout of the code before")
    ap.add_argument("--passes", type=int, default=5, help="pairs of runs, before then after")
    ap.add_argument("--out", type=Path, required=True, help="where the JSON goes")
    args = ap.parse_args(argv[:cut])
    bench = argv[cut + 1:]
    if not bench:
        raise SystemExit("side_by_side: no benchmark after --")
    script, bench_args = bench[0], bench[1:]
    trees = {"before": args.before.resolve(), "after": ROOT}
    for tree in trees.values():
        if not (tree / script).is_file():
            raise SystemExit(f"side_by_side: {tree / script}: no such benchmark")
    runs = []
    with tempfile.TemporaryDirectory(prefix="side-by-side-") as tmp:
        for n in range(1, args.passes + 1):
            for code, tree in trees.items():
                print(f"pass {n}/{args.passes}: {code}", file=sys.stderr, flush=True)
                report = run_once(tree, script, bench_args, Path(tmp) / f"{code}{n}.json")
                runs.append({"code": code, "pass": n, "report": report})
    result = {"benchmark": "side by side", "command": " ".join(["python", script, *bench_args]),
              "before": git_rev(trees["before"]), "after": git_rev(ROOT),
              "passes": args.passes, "runs": runs, "machine": platform.machine()}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    return result


if __name__ == "__main__":
    main()
