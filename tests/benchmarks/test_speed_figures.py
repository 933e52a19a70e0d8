"""The simulator-speed and tuning figures in docs/performance.md and docs/tuning.md are the
committed benchmarks' (`benchmarks/run_bench.py --before`, `benchmarks/tune_bench.py`:
minutes of real time, not rerun here): every row of their tables is checked against the
JSON, and a run whose counts differed between the checkouts is refused."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"


def _doc(name: str) -> str:
    return (ROOT / "docs" / name).read_text()


def test_the_speed_table_quotes_the_side_by_side_run():
    hour = json.loads((RESULTS / "simspeed_300x.json").read_text())["side_by_side"]
    thesis = json.loads((RESULTS / "simspeed_300x_thesis.json").read_text())["side_by_side"]
    assert hour["counts_same"] and thesis["counts_same"]
    doc = _doc("performance.md")
    for r in hour["table"]:
        b, a = r["before"], r["after"]
        assert b["counts"] == a["counts"]
        row = (f"| {r['seed']} | {b['parts_per_minute']:.3f} | {a['parts_per_minute']:.3f} | "
               f"{', '.join(f'{s:.0f}×' for s in b['sim_per_wall_runs'])} | "
               f"{', '.join(f'{s:.0f}×' for s in a['sim_per_wall_runs'])} | "
               f"{b['cpu_s_per_sim_hour']:.1f} | {a['cpu_s_per_sim_hour']:.1f} | ")
        assert row in doc, row
    for r in thesis["table"]:
        row = (f"| {r['seed']} | {r['before']['parts_per_minute']:.3f} | "
               f"{r['after']['parts_per_minute']:.3f} |")
        assert row in doc, row
    after = hour["components"]["after"]
    assert f"| **{hour['components']['before']['cpu_s_per_sim_hour']:.2f}** | " \
           f"**{after['cpu_s_per_sim_hour']:.2f}** |" in doc


def test_the_rerun_at_this_round_s_code_is_quoted_and_its_counts_agree():
    rerun = json.loads((RESULTS / "simspeed_300x_rerun.json").read_text())["side_by_side"]
    assert rerun["counts_same"]
    doc = _doc("performance.md")
    for r in rerun["table"]:
        b, a = r["before"], r["after"]
        assert b["counts"] == a["counts"]
        assert min(a["sim_per_wall_runs"]) >= 300          # the goal, every run
        row = (f"| {r['seed']} | {b['parts_per_minute']:.3f} | {a['parts_per_minute']:.3f} | "
               f"{', '.join(f'{s:.0f}×' for s in b['sim_per_wall_runs'])} | "
               f"{', '.join(f'{s:.0f}×' for s in a['sim_per_wall_runs'])} | "
               f"{b['cpu_s_per_sim_hour']:.1f} | {a['cpu_s_per_sim_hour']:.1f} | "
               f"{b['sim_per_cpu']:.0f}× | {a['sim_per_cpu']:.0f}× |")
        assert row in doc, row


def test_the_tune_figures_quote_the_committed_benchmark():
    tune = json.loads((RESULTS / "tune.json").read_text())
    assert len(tune["searches"]) == 3
    median = sorted(s["of_fixed"] for s in tune["searches"])[1]
    assert tune["median_of_fixed"] == median
    perf = _doc("performance.md")
    assert f"**Median of the three: {100 * median:.1f} %**" in perf
    assert f"**{tune['fixed']['mean']:.2f}** parts/min" in perf
    for s in tune["searches"]:
        assert f"{s['fresh']['mean']:.2f} (sd {s['fresh']['sd']:.2f})" in perf
    assert (f"a setting whose mean on 5 fresh seeds is {100 * median:.1f} % of the grid-best"
            in " ".join(_doc("tuning.md").split()))
