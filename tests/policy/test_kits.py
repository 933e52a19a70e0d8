"""Kits (thesis 8.2.1.5): the retrieve tree takes the part types the kit being
built still lacks; a kit advances when a part is placed, never when one is only chosen;
the report counts kits and bounds them."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest

from feeder_bt.analysis.summary import summary
from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.policy.kits import KitTracker, kit_bounds

ROOT = Path(__file__).resolve().parents[2]


def test_a_kit_in_any_order_wants_what_it_lacks():
    kit = KitTracker({"square": 1, "lens": 3})
    assert kit.wanted() == {"square", "lens"}
    assert kit.placed("lens") is False and kit.placed("lens") is False
    assert kit.placed("lens") is False and kit.wanted() == {"square"}
    assert kit.placed("lens") is False and kit.have["lens"] == 3    # not wanted: not counted
    assert kit.placed("square") is True and kit.completed == 1
    assert kit.wanted() == {"square", "lens"}                       # the next kit


def test_a_sequence_is_a_kit_in_order_and_waits_for_its_part():
    kit = KitTracker({"washer": 1, "nut": 1}, ["washer", "nut"])
    assert kit.wanted() == {"washer"}
    assert kit.placed("nut") is False and kit.wanted() == {"washer"}  # a nut out of turn
    # a missed washer pick places nothing: the kit still wants the washer
    assert kit.wanted() == {"washer"}
    assert kit.placed("washer") is False and kit.wanted() == {"nut"}
    assert kit.placed("nut") is True and kit.completed == 1


def test_parts_on_their_way_are_promised_to_the_kit():
    """Robots of the part server hold parts not yet placed: the kit does not ask for
    them again."""
    kit = KitTracker({"square": 1, "lens": 3})
    assert kit.wanted(Counter(square=1, lens=2)) == {"lens"}
    assert kit.wanted(Counter(square=1, lens=3)) == set()         # all on their way
    seq = KitTracker({"washer": 1, "nut": 1}, ["washer", "nut"])
    assert seq.wanted(Counter(washer=1)) == {"nut"}
    assert seq.wanted(Counter(washer=1, nut=1)) == set()


def test_kit_bounds_are_the_lowest_of_robot_supply_and_inflow():
    b = kit_bounds({"square": 1, "lens": 3}, {"square": 30, "lens": 300}, 60.0, 100.0,
                   {"square": (10, [(30.0, 5)]), "lens": (100, [])}, 60.0)
    assert b["robot_bound_kpm"] == 25.0                   # 100 parts/min over 4 a kit
    assert b["supply_bound_kpm"] == 30.0                  # squares: 30 in reach, 1 a kit
    assert b["inflow_bound_kpm"] == pytest.approx(15.0)   # 15 squares came in all
    assert b["ceiling_kpm"] == min(b["robot_bound_kpm"], b["supply_bound_kpm"],
                                   b["inflow_bound_kpm"])
    # the ride to the robot: squares arriving at 30 s reach it at 70 s, after the run;
    # nothing reaches the robot before 40 s, and then it builds a kit every 4 cycles:
    # 100 / 4 kits a minute over the 20 s left, plus one begun before
    late = kit_bounds({"square": 1, "lens": 3}, {"square": 30, "lens": 300}, 60.0, 100.0,
                      {"square": (10, [(30.0, 5)]), "lens": (100, [])}, 60.0, lag_s=40.0)
    assert late["inflow_bound_kpm"] == pytest.approx(25.0 * 20.0 / 60.0 + 1.0, abs=1e-3)


def test_the_kit_inflow_bound_charges_a_kit_its_whole_size_of_robot_cycles():
    """Scarce squares arriving late: once the last one is in, the robot still needs the
    lenses of its kit, so the kits after ``s`` come at the robot's rate over the kit's
    size, not over the square's count of it."""
    b = kit_bounds({"square": 1, "lens": 3}, {"square": 100, "lens": 300}, 60.0, 60.0,
                   {"square": (0, [(50.0, 20)]), "lens": (300, [])}, 60.0)
    # just before the squares came: none yet, then 15 kits/min for the last 10 s, + 1
    assert b["inflow_bound_kpm"] == pytest.approx(15.0 * 10.0 / 60.0 + 1.0)
    # the parts' form (a square at every robot cycle) would allow 60 * 10 / 60 + 1 = 11
    assert b["inflow_bound_kpm"] < 11.0
    # the nearest-first replay's kits are a yardstick: beside the bounds, never the ceiling
    got = kit_bounds({"square": 1, "lens": 3}, {"square": 100, "lens": 300}, 60.0, 60.0,
                     None, 60.0, selection_kits=3)
    assert got["selection_bound_kpm"] == 3.0 and got["ceiling_kpm"] == 15.0


def kit_scenario(tmp_path: Path, kit: str) -> Path:
    text = (ROOT / "scenarios" / "lenses_and_squares.yaml").read_text()
    text = text.replace("cell: ../cells/", f"cell: {ROOT / 'cells'}/")
    old = "  too_far_mm: 1190\n"
    assert old in text
    p = tmp_path / "kits.yaml"
    p.write_text(text.replace(old, old + f"  kit: {kit}\n", 1))
    return p


def test_a_run_builds_kits_in_their_proportions(tmp_path):
    r = run_job(RunOptions(scenario=str(kit_scenario(tmp_path, "{square: 1, lens: 3}")),
                           duration=600.0, fast=True, seed=2, view="none", db=None,
                           supply=str(ROOT / "supply" / "mix_drift.yaml")))
    k, got = r["kits"], r["parts"]["retrieved"]
    assert k["completed"] > 50 and r["parts"]["lost"] == 0
    # every placed part went into a kit: the last one may be half built
    assert k["completed"] <= got["square"] <= k["completed"] + 1
    assert 3 * k["completed"] <= got["lens"] <= 3 * k["completed"] + 3
    assert k["per_minute"] == pytest.approx(k["completed"] / 10.0, abs=1e-3)
    assert 0 < k["per_minute"] <= k["ceiling_kpm"] and "inflow_bound_kpm" in k
    # a nearest-first robot taking only the wanted types, over the same passes
    assert k["per_minute"] <= k["selection_bound_kpm"] <= r["robot_bound_selection_ppm"] / 4
    assert f"kits {k['completed']} (1 square + 3 lens)" in summary(r)
    lowest = min((n for n in k if n.endswith("_bound_kpm") and n != "selection_bound_kpm"),
                 key=k.get)
    assert f"of the kit ceiling {k['ceiling_kpm']:.1f} ({lowest[:-10]} bound)" in summary(r)
    # the steady-state bound at the measured cycle: the run's cycles, in kits
    assert k["steady_at_cycle_kpm"] == pytest.approx(
        sum(got.values()) / 10.0 / 4, abs=1e-3)
    assert k["per_minute"] <= k["steady_at_cycle_kpm"]
    assert f"at the measured {k['robot_cycle_s']:.2f} s cycle" in summary(r)
    free = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "lenses_and_squares.yaml"),
                              duration=600.0, fast=True, seed=2, view="none", db=None,
                              supply=str(ROOT / "supply" / "mix_drift.yaml")))
    assert "kits" not in free and "kits " not in summary(free)
    # without a kit nothing is held back: more of each type, more in all; its lens:square
    # ratio is the supply's and the prices' (close to 3:1 by chance, so not asserted)
    fr = free["parts"]["retrieved"]
    assert fr["square"] > got["square"] + 20 and fr["lens"] > got["lens"] + 60


@pytest.mark.parametrize("kit, what", [
    ("{square: 1, lense: 3}", "retrieve.kit.lense: unknown part 'lense'"),
    ("{square: 0, lens: 3}", "retrieve.kit.square: must be a whole number >= 1"),
])
def test_a_bad_kit_is_one_line_and_exit_2(tmp_path, capsys, kit, what):
    assert main(["check", str(kit_scenario(tmp_path, kit))]) == 2
    err = capsys.readouterr().err.strip()
    assert what in err and "Traceback" not in err


def test_a_kit_and_a_sequence_together_are_refused(tmp_path, capsys):
    p = kit_scenario(tmp_path, "{square: 1, lens: 3}")
    p.write_text(p.read_text().replace("  kit:", "  sequence: [square, lens]\n  kit:"))
    assert main(["check", str(p)]) == 2
    assert "not both" in capsys.readouterr().err


def test_two_open_kits_take_what_either_lacks_and_fill_the_fuller_first():
    """retrieve.open_kits: two trays at the station; a lens need not wait for the square
    the first tray lacks, and a part goes to the fuller tray, so kits leave sooner."""
    kit = KitTracker({"square": 1, "lens": 3}, open_kits=2)
    for _ in range(3):
        assert kit.placed("lens") is False
    assert kit.wanted() == {"square", "lens"}       # tray 1 lacks a square, tray 2 anything
    assert kit.placed("lens") is False              # into tray 2: tray 1 has its lenses
    assert [sorted(k.items()) for k in kit.kits] == [[("lens", 3)], [("lens", 1)]]
    assert kit.placed("square") is True and kit.completed == 1   # the fuller tray first
    assert kit.placed("square") is False and kit.wanted() == {"square", "lens"}
    assert kit.have == Counter(square=1, lens=1)     # the fullest open kit
    one = KitTracker({"square": 1, "lens": 3})
    for _ in range(4):
        one.placed("lens")
    assert one.wanted() == {"square"} and one.have["lens"] == 3   # one tray: the lens waits


def test_open_kits_in_order_each_want_their_next_and_count_promises():
    seq = KitTracker({"washer": 1, "nut": 1}, ["washer", "nut"], open_kits=2)
    assert seq.placed("nut") is False and seq.placed("washer") is False
    assert seq.wanted() == {"washer", "nut"}         # kit 1 its nut, kit 2 its washer
    assert seq.wanted(Counter(nut=1)) == {"washer"}
    assert seq.wanted(Counter(nut=1, washer=1)) == {"nut"}
    assert seq.placed("nut") is True and seq.completed == 1


def test_the_kit_inflow_bound_allows_one_kit_begun_per_open_kit():
    """Kits done by the end <= A(s)/n + R/size (T - s) + the kits open at s: with two
    trays, two kits may be under way when the last part arrives."""
    inflow = {"lens": (0, [(300.0, 30)]), "square": (30, [])}
    one = kit_bounds({"square": 1, "lens": 3}, {}, 600.0, 60.0, inflow, 600.0)
    two = kit_bounds({"square": 1, "lens": 3}, {}, 600.0, 60.0, inflow, 600.0, open_kits=2)
    # nothing before 300 s, then 15 kits/min for 300 s (75) but 10 lens kits at most
    assert one["inflow_bound_kpm"] == round(10 * 60 / 600, 3)
    assert two["inflow_bound_kpm"] == one["inflow_bound_kpm"]  # the arrivals still decide
    late = {"lens": (0, [(590.0, 300)]), "square": (300, [])}
    one = kit_bounds({"square": 1, "lens": 3}, {}, 600.0, 60.0, late, 600.0)
    two = kit_bounds({"square": 1, "lens": 3}, {}, 600.0, 60.0, late, 600.0, open_kits=2)
    # 10 s before the end: 15 kits/min for 10 s = 2.5, plus the kits begun
    assert one["inflow_bound_kpm"] == round(3.5 * 60 / 600, 3)
    assert two["inflow_bound_kpm"] == round(4.5 * 60 / 600, 3)


def test_a_second_open_kit_builds_more_kits(tmp_path):
    """With one tray a lens waits while the tray lacks its square; with two it goes to the
    second tray. Same seed, same setting: more kits, every placed part in a kit but those
    of the trays still open, nothing lost."""
    runs = {}
    for n in (1, 2):
        p = kit_scenario(tmp_path, "{square: 1, lens: 3}")
        if n > 1:
            p.write_text(p.read_text().replace("  kit:", f"  open_kits: {n}\n  kit:"))
        runs[n] = run_job(RunOptions(scenario=str(p), duration=600.0, fast=True, seed=2,
                                     view="none", db=None,
                                     supply=str(ROOT / "supply" / "mix_drift.yaml")))
    one, two = runs[1], runs[2]
    assert two["kits"]["completed"] > one["kits"]["completed"]
    assert two["kits"]["open_kits"] == 2 and two["parts"]["lost"] == 0
    got, k = two["parts"]["retrieved"], two["kits"]["completed"]
    assert k <= got["square"] <= k + 2 and 3 * k <= got["lens"] <= 3 * k + 6
    assert "2 open at once" in summary(two)


@pytest.mark.parametrize("edit, what", [
    ("  open_kits: 0\n  kit:", "retrieve.open_kits"),
    ("  open_kits: 2\n  kitx:", "retrieve.open_kits: open kits need a retrieve.kit"),
])
def test_bad_open_kits_are_one_line_and_exit_2(tmp_path, capsys, edit, what):
    p = kit_scenario(tmp_path, "{square: 1, lens: 3}")
    text = p.read_text().replace("  kit:", edit)
    if "kitx" in edit:          # no kit at all: drop the kit line
        text = "\n".join(x for x in text.splitlines() if not x.startswith("  kitx:")) + "\n"
    p.write_text(text)
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert what in err and "Traceback" not in err and len(err.splitlines()) == 1


def test_feeder_report_gives_a_kit_runs_kits_minute_by_minute(tmp_path, capsys):
    db = tmp_path / "k.db"
    kits = run_job(RunOptions(scenario=str(ROOT / "scenarios" / "kits_lenses_squares.yaml"),
                              duration=150.0, fast=True, seed=3, view="none", db=str(db),
                              supply=str(ROOT / "supply" / "mix_drift.yaml")))
    run_job(RunOptions(scenario=str(ROOT / "scenarios" / "lenses.yaml"), duration=30.0,
                       fast=True, seed=3, view="none", db=str(db)))
    capsys.readouterr()
    assert main(["report", str(db)]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if " kits " in ln]
    (line,) = lines                              # the kit run's, not the lenses run's
    said = summary(kits).split("\n  kits ", 1)[1].split("\n", 1)[0]
    assert line.startswith(f"run 1 kits {said}; by minute of feeding: ")
    by_minute = [int(n) for n in line.split("feeding: ")[1].split(" (")[0].split()]
    assert len(by_minute) == 3 and line.endswith("(the last over 30 s)")
    assert sum(by_minute) == kits["kits"]["completed"] > 0
    assert main(["report", str(db), "--run", "1", "--json"]) == 0
    got = json.loads(capsys.readouterr().out)["kits"]
    assert got["by_bin"] == by_minute and got["bin_s"] == 60.0 and got["last_bin_s"] == 30.0
    # a long run's pace in at most 30 bins of whole minutes; a damaged length: no bins
    import sqlite3
    conn = sqlite3.connect(db)
    rep = json.loads(conn.execute("SELECT report FROM runs WHERE id=1").fetchone()[0])
    for feed, want in ((7200.0, "; by 4 minutes of feeding: "), ("x", None), (1e300, None)):
        rep["feed_seconds"] = feed
        conn.execute("UPDATE runs SET report=? WHERE id=1", (json.dumps(rep),))
        conn.commit()
        code = main(["report", str(db), "--run", "1"])
        out, err = capsys.readouterr()
        if want is None:
            assert "by " not in out and "Traceback" not in err
        else:
            assert code == 0 and want in out
            assert len(out.split(want)[1].split("\n")[0].split(" (")[0].split()) == 30
    conn.close()
