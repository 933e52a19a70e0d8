"""Run the real-time soak tests, which the default test run leaves out, and record them.

    python benchmarks/soak.py [--out benchmarks/results/soak.json] [PYTEST ARGS...]

The soak tests (``@pytest.mark.soak``) take minutes of wall clock because they run the
cell in real time: ten minutes of feeding through the emulators while the Galil's and the
Adept's connections are cut every 75 s (a pulled cable), and the README's whole minute of
``feeder run scenarios/lenses.yaml`` in an 80 x 24 pseudo-terminal. This is the same as
``python -m pytest -m soak``, with each test named as it starts (so a ten-minute test is
not mistaken for a hung one) and the outcome and wall time of each written as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "soak.json"))
    args, extra = ap.parse_known_args()
    junit = Path(args.out).with_suffix(".xml")
    junit.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    # -n 0: one process, so -v names each test when it starts
    rc = subprocess.call([sys.executable, "-m", "pytest", "-m", "soak", "-n", "0", "-v",
                          "--durations=0", f"--junitxml={junit}", *extra], cwd=ROOT)
    tests = []
    if junit.exists():
        for case in ET.parse(junit).iter("testcase"):
            outcome = "passed"
            for tag in ("failure", "error", "skipped"):
                if case.find(tag) is not None:
                    outcome = {"failure": "failed"}.get(tag, tag)
            tests.append({"test": f"{case.get('classname')}::{case.get('name')}",
                          "outcome": outcome, "seconds": round(float(case.get("time", 0)), 1)})
        junit.unlink()
    Path(args.out).write_text(json.dumps({
        "command": " ".join(["python -m pytest -m soak", *extra]), "exit_code": rc,
        "wall_seconds": round(time.monotonic() - t0, 1), "tests": tests,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                    "load_after": os.getloadavg()},
    }, indent=2) + "\n")
    print(f"wrote {args.out}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
