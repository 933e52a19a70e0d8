"""The figures docs/performance.md quotes for the thesis table and the plant's budget table
are the committed benchmark JSON's (`python benchmarks/honest_bench.py --only thesis`,
`benchmarks/frontier_bench.py`, `honest_bench.py --only tuned --max-recirc 1.5`)."""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "benchmarks" / "results"


def _doc() -> str:
    return (ROOT / "docs" / "performance.md").read_text()


def test_the_thesis_table_is_honest_json():
    t = json.loads((RESULTS / "honest.json").read_text())["thesis"]
    text = _doc()
    for label, key in (("original CWRU feeder", "original"),
                       ("new feeder, thesis's water marks", "new_water_marks")):
        m = re.search(rf"^\| {re.escape(label)} \| \*\*([\d.]+)\*\* \(([\d.]+)–([\d.]+), sd "
                      rf"([\d.]+)\) \|", text, flags=re.M)
        assert m, label
        r = t[key]
        assert tuple(map(float, m.groups())) == (r["mean"], r["min"], r["max"], r["stdev"])
    m = re.search(r"^\| ratio \| \*\*([\d.]+)×\*\* \|", text, flags=re.M)
    assert m and float(m.group(1)) == round(t["ratio"], 2)
    flat = " ".join(text.split())
    new = t["new_water_marks"]
    assert (f"the thesis's water marks {new['recirc_per_placed']:.2f} (`recirc_per_placed` in "
            f"`honest.json`)") in flat
    assert (f"the new feeder at {100 * new['of_ceiling']:.1f} % of its ceiling (the supply "
            f"bound, {new['ceiling_ppm']:.1f}) and {new['of_selection_bound']:.3f}× its "
            f"selection yardstick {new['selection_bound_ppm']:.1f}") in flat
    assert f"original sits at {100 * t['original']['of_ceiling']:.1f} % of its ceiling" in flat


def test_the_budget_table_is_the_frontier_and_the_budget_runs():
    best = json.loads((RESULTS / "frontier.json").read_text())["best_fixed"]
    ours = json.loads((RESULTS / "honest_budget.json").read_text())["tuned"]["ours"]
    text = _doc()
    m = re.search(r"^\| fixed setting, gridded \(frontier below\): lookahead, belt 260 mm/s, "
                  r"incline 38\.46 % \| \*\*([\d.]+)\*\* \(sd ([\d.]+)\) \| ([\d.]+)× of "
                  r"([\d.]+) \| (\d+) % \| ([\d.]+) \|$", text, flags=re.M)
    assert m
    assert tuple(map(float, m.groups())) == (
        best["mean"], best["sd"], round(best["mean"] / best["selection_bound_ppm"], 2),
        best["selection_bound_ppm"], round(best["robot_busy_pct"]),
        round(best["recirc_per_placed"], 2))
    policy = ours["setting"].split(" + ")[1]            # what the search kept
    m = re.search(r"^\| ours = thesis's water marks with every option, tuned: water marks \+ "
                  rf"{policy} \| ([\d.]+) \(([\d.]+)–([\d.]+), sd ([\d.]+)\) \| ([\d.]+)× of "
                  r"([\d.]+) \| (\d+) % \| ([\d.]+) \|$", text, flags=re.M)
    assert m
    assert tuple(map(float, m.groups())) == (
        ours["mean"], ours["min"], ours["max"], ours["stdev"],
        round(ours["of_selection_bound"], 2), round(ours["selection_bound_ppm"], 1),
        round(ours["robot_busy_pct"]), ours["recirc_per_placed"])
    m = re.search(r"^\| ours / the gridded fixed setting \| \*\*([\d.]+)×\*\*", text, flags=re.M)
    assert m and float(m.group(1)) == round(ours["mean"] / best["mean"], 3)
    assert "1.143×" not in text           # no ratio against a baseline the docs say was beaten


def test_the_adjuster_policy_grid_is_throughput_json():
    """docs/performance.md's two grids and the original feeder's line, cell for cell."""
    result = json.loads((ROOT / "benchmarks/results/throughput.json").read_text())
    by = {(r["scenario"], r["adjuster"], r["policy"]): r for r in result["summary"]}
    text = (ROOT / "docs/performance.md").read_text()
    policies = ("fifo", "earliest_deadline", "shortest_cycle", "lookahead")
    for scenario in ("lenses", "squares"):
        table = text[text.index(f"**{scenario}** (robot bound "):].split("\n\n")[1]
        rows = re.findall(r"^\| `(\w+)` \| (.+) \|$", table, flags=re.M)
        assert [a for a, _ in rows] == ["none", "queue_proportional", "water_marks",
                                        "supply_queue"]
        for adjuster, cells in rows:
            quoted = re.findall(r"([\d.]+) \(([\d.]+)–([\d.]+)\)", cells)
            want = [tuple(f"{by[scenario, adjuster, p][k]:.1f}"
                          for k in ("ppm_mean", "ppm_min", "ppm_max")) for p in policies]
            assert quoted == want, (scenario, adjuster)
    o = by["original_cwru_lenses", "scenario", "scenario"]
    assert (f"Original CWRU feeder, as shipped: {o['ppm_mean']:.2f} ({o['ppm_min']:.2f}–"
            f"{o['ppm_max']:.2f}) parts/min.") in text
    assert len(result["runs"]) == 165 and all(r["lost"] == 0 for r in result["runs"])


def test_the_sensitivity_table_is_sensitivity_json():
    """docs/performance.md's "What moves the thesis table most", row for row."""
    result = json.loads((RESULTS / "sensitivity.json").read_text())
    text = _doc()
    table = text[text.index("| change (one at a time) |"):].split("\n\n")[0]
    rows = re.findall(r"^\| ([^|]+) \| ([^|]+) \| ([^|]+) \| ([^|]+) \|$", table, flags=re.M)[1:]

    def cell(x):
        return f"{x['mean']:.1f} ({x['min']:.1f}–{x['max']:.1f})" if x else "—"
    want = [(r["variant"], cell(r["new"]), cell(r["original"]),
             f"{r['ratio']:.2f}" if r.get("ratio") is not None else "—")
            for r in result["rows"]]
    assert rows == want
    first = result["rows"][0]
    assert first["variant"] == "as documented"
    assert (f"at 1800 s for the original ({first['original']['mean']:.2f} against") in \
        " ".join(text.split())


def test_the_tuned_tables_are_their_json():
    """The batch-refill and ample-supply tables (found, fresh-seed mean, min–max, sd) and
    their ratios are honest_batch_refill.json's and honest_tuned.json's."""
    text = _doc()
    flat = " ".join(text.split())
    for name, heading in (("honest_batch_refill.json", "### Under batch refill"),
                          ("honest_tuned.json", "### With ample supply")):
        tuned = json.loads((RESULTS / name).read_text())["tuned"]
        section = text[text.index(heading):]
        table = section[section.index("| setting (same budget) |"):].split("\n\n")[0]
        rows = re.findall(r"^\| [^|]+ \| ([\d.]+) \| \**([\d.]+)\** \(([\d.]+)–([\d.]+), "
                          r"sd ([\d.]+)\) \|", table, flags=re.M)
        want = [(f"{t['tuned_ppm']:.2f}", f"{t['mean']:.2f}", f"{t['min']:.2f}",
                 f"{t['max']:.2f}", f"{t['stdev']:.2f}")
                for t in (tuned[k] for k in ("ours", "watermarks", "fixed"))]
        assert rows == want, name
        assert (f"Ours is **{tuned['ours_vs_watermarks']:.3f}×** the tuned water marks and "
                f"**{tuned['ours_vs_fixed']:.3f}×** the best fixed setting") in flat, name


def test_the_batch_refill_example_is_the_tuned_fixed_setting():
    """examples/batch_refill_best.yaml (docs/supply.md runs it) is honest_batch_refill.json's
    best fixed setting."""
    import yaml
    tuned = json.loads((RESULTS / "honest_batch_refill.json").read_text())["tuned"]
    shipped = yaml.safe_load((ROOT / "examples" / "batch_refill_best.yaml").read_text())
    assert shipped == tuned["fixed"]["overlay"]
