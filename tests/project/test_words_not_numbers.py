"""Code, tests and docs say why in words: no "issue N", naming a tracker that users of the
project cannot see."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TRACKER = re.compile(r"\bissues? #?\d", re.IGNORECASE)
TEXT = (".py", ".md", ".yaml", ".yml", ".toml", ".js", ".html", ".css", ".v2", ".dmc",
        ".script", ".mod")


def test_nothing_names_the_tracker_by_number():
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True,
                           check=True).stdout.split()
    found = []
    for name in files:
        if (not name.endswith(TEXT) or name.startswith("benchmarks/results/")
                or name == "tests/project/test_words_not_numbers.py"):
            continue
        path = ROOT / name
        if not path.is_file():
            continue
        for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace")
                                 .splitlines(), 1):
            if TRACKER.search(line):
                found.append(f"{name}:{i}: {line.strip()[:100]}")
    assert found == []


def test_the_check_finds_a_reference():
    assert TRACKER.search("the fix (issue 31)") and TRACKER.search("Issue #7 says")
    assert not TRACKER.search("an issue with the belt") and not TRACKER.search("issues")
