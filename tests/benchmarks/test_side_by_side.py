"""benchmarks/side_by_side.py: one benchmark in two checkouts by turns (no timing here)."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("side_by_side",
                                               ROOT / "benchmarks" / "side_by_side.py")
sbs = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(sbs)

FAKE = """import json, sys
from pathlib import Path
out = Path(sys.argv[sys.argv.index("--out") + 1])
if "--fail" in sys.argv:
    sys.exit("boom: the bench broke")
out.write_text(json.dumps({"tree": Path(__file__).resolve().parents[1].name,
                           "args": sys.argv[1:-2]}))
"""


def test_passes_take_turns_before_then_after_and_keep_each_report(tmp_path, monkeypatch):
    before, after = tmp_path / "old", tmp_path / "new"
    for tree in (before, after):
        (tree / "benchmarks").mkdir(parents=True)
        (tree / "benchmarks" / "fake.py").write_text(FAKE)
    monkeypatch.setattr(sbs, "ROOT", after)
    out = tmp_path / "r.json"
    got = sbs.main(["--before", str(before), "--passes", "2", "--out", str(out), "--",
                    "benchmarks/fake.py", "--x", "1"])
    assert json.loads(out.read_text()) == got
    assert [(r["code"], r["pass"], r["report"]["tree"]) for r in got["runs"]] == [
        ("before", 1, "old"), ("after", 1, "new"), ("before", 2, "old"), ("after", 2, "new")]
    assert all(r["report"]["args"] == ["--x", "1"] for r in got["runs"])
    assert got["command"] == "python benchmarks/fake.py --x 1"
    with pytest.raises(SystemExit, match=r"fake\.py in .*old failed: boom: the bench broke"):
        sbs.main(["--before", str(before), "--out", str(out), "--", "benchmarks/fake.py",
                  "--fail"])
    with pytest.raises(SystemExit, match="no such benchmark"):
        sbs.main(["--before", str(before), "--out", str(out), "--", "benchmarks/nope.py"])
    with pytest.raises(SystemExit, match="give the benchmark after --"):
        sbs.main(["--before", str(before), "--out", str(out)])
