"""Docs that cannot go stale: every command output quoted in docs/ under an
``<!-- output: ... -->`` marker, and every figure under ``<!-- figure: ... -->``, is what
the commands print now (`python docs/build.py` rewrites them; `--check` is this test)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("docs_build", ROOT / "docs/build.py")
build = importlib.util.module_from_spec(spec)
sys.modules["docs_build"] = build              # its dataclass looks itself up there
spec.loader.exec_module(build)


def test_the_docs_quote_what_they_must():
    cmds = " ".join(q.cmds for q in build.quotes())
    assert "recipe suggest scenarios/hex_nuts.yaml" in cmds          # the stale ones of #29
    assert "locate scenarios/brackets_dark.yaml" in cmds
    assert "--faults faults/shift.yaml" in cmds
    assert "--target acircles --board 7x13" in cmds           # real circle grids
    assert [png for _, _, png in build.figures()] == ["report-example.png"]


@pytest.mark.soak      # reruns every quoted command: a minute
def test_every_quoted_output_and_figure_is_current():
    bad = build.check(build.quotes())
    assert not bad, "\n".join(bad)


@pytest.mark.soak      # reruns every quoted command: a minute
def test_an_edited_quote_fails_and_the_wall_clock_does_not(tmp_path):
    doc = tmp_path / "adding-a-part.md"
    text = (ROOT / "docs/adding-a-part.md").read_text()
    for old, new, stale in [("finds 4 part(s)", "finds 6 part(s)", True),    # the docs'
                            ("frame_002.png: 0 part(s), 0 rejected, ",
                             "frame_002.png: 0 part(s), 0 rejected, 12.5 ms;", True),
                            (" ms\n", " ms\n", False)]:
        assert old in text
        doc.write_text(text.replace(old, new, 1))
        q = next(q for q in build.quotes([doc]) if "brackets_dark" in q.cmds)
        assert bool(build.check([q])) is stale, old


def test_numbers_compare_exactly_unless_a_tolerance_is_stated():
    assert build.same("66.7 parts/min (1.7 s wall), 2.4 ms", "66.7 parts/min (9.0 s wall), 0.6 ms")
    assert not build.same("68.2 parts/min", "66.7 parts/min")
    assert build.same("68.2 parts/min", "67.5 parts/min", rel_tol=0.02)
    assert not build.same("68.2 parts/min", "66.7 parts/min", rel_tol=0.02)
    assert not build.same("area_mm2: [750, 839]", "area_mm2: [750, 839], aspect: [1, 2]")


def test_the_shift_table_quotes_the_committed_benchmark():
    """Eight-hour benchmarks are not rerun here: their figures in docs/faults.md must be
    the ones benchmarks/results/shift.json holds (`python benchmarks/shift_bench.py`)."""
    import json
    import re

    runs = json.loads((ROOT / "benchmarks/results/shift.json").read_text())["runs"]
    by = {(r["seed"], r["faults"]): r for r in runs}
    rows = re.findall(r"^\| (\d) \| STOPPED after (\d+) s \| (\d) \| ([\d.]+) \| ([\d.]+) \| "
                      r"([\d.]+) % \| (\d+) \| (\d+) \|",
                      (ROOT / "docs/faults.md").read_text(), flags=re.M)
    assert len(rows) == len({s for s, _ in by}) >= 5
    for seed, end, code, ppm_f, ppm_c, ratio, lost, dup in rows:
        f, c = by[(int(seed), True)], by[(int(seed), False)]
        assert float(ppm_f) == round(f["parts_per_minute"], 2), seed
        assert float(ppm_c) == round(c["parts_per_minute"], 2), seed
        assert float(ratio) == round(100 * f["parts_per_minute"] / c["parts_per_minute"], 1)
        assert int(code) == f["exit_code"] and int(lost) == f["lost"]
        assert int(dup) == f["duplicated"] and abs(int(end) - f["sim_seconds"]) < 1


def test_the_flood_figures_quote_the_committed_benchmark():
    """The flood figures in the docs are benchmarks/results/flood.json's
    (`python benchmarks/flood.py`, minutes of real time: not rerun here)."""
    import json
    import re

    got = json.loads((ROOT / "benchmarks/results/flood.json").read_text())
    ui_doc = (ROOT / "docs/operator-ui.md").read_text()
    ui = got["ui"]
    assert (f"alice's `/api/me` answered in {ui['me_s']:.2f} s and her Stop in "
            f"{ui['stop_s']:.2f} s") in " ".join(ui_doc.split())
    for key, where in (("holder", "from her own address"),
                       ("holder_via_proxy", "through the proxy's one address")):
        h = got[key]
        m = re.search(re.escape(where) + r": (\d+) of (\d+) `/api/me` and (\d+) of (\d+) "
                      r"Stops answered, (\d+) within 1 s \(median (\d+) ms, slowest (\d+) ms\)",
                      " ".join(ui_doc.split()))
        assert m, where
        assert [int(x) for x in m.groups()] == [
            h["me_answered"], h["rounds"], h["stop_answered"], h["rounds"],
            h["stop_within_1s"], round(1000 * h["stop_median_s"]),
            round(1000 * h["stop_max_s"])], where
    ps = got["part_server"]
    assert (f"a new robot had its first answer in {round(1000 * ps['first_answer_s'])} ms "
            f"and a part in {round(1000 * ps['part_s'])} ms") in \
        " ".join((ROOT / "docs/part-server.md").read_text().split())
    ua = got["opcua"]
    plant = " ".join((ROOT / "docs/plant.md").read_text().split())
    assert (f"logged in and read `State` in {ua['connect_login_read_s']:.2f} s") in plant
    own = got["opcua_own_address"]
    assert (f"{own['got_in']} of {own['rounds']} got in (median "
            f"{round(1000 * own['median_s'])} ms, slowest {round(1000 * own['max_s'])} ms)"
            ) in plant
