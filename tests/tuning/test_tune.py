"""`feeder tune` and scenario overlays: every trial legal, the overlay applied and checked,
a study that resumes, the same search on a local Dask cluster, the search's plot.

Tiny searches (20 simulated seconds, one seed, two or three trials) in virtual time."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.cli.main import main
from feeder_bt.config import load_scenario
from feeder_bt.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
LENSES = str(ROOT / "scenarios" / "lenses.yaml")
SQUARES = str(ROOT / "scenarios" / "squares.yaml")
TINY = ["--duration", "20", "--seeds", "1", "--max-recirc", "off"]   # 20 s: nothing recirculates
WHOLE = ["--no-halving"]          # every trial run whole: values the tests can compare


def _write(path: Path, text: str) -> str:
    path.write_text(text)
    return str(path)


# --------------------------------------------------------------------------- overlays

def test_overlay_merges_over_the_scenario(tmp_path):
    base, _ = load_scenario(LENSES)
    ov = _write(tmp_path / "o.yaml", "retrieve:\n  policy: lookahead\n"
                                     "present:\n  horizontal_mm_s: 220\n")
    sc, _ = load_scenario(LENSES, overlay=ov)
    assert sc.retrieve.policy == "lookahead" and sc.present.horizontal_mm_s == 220
    assert sc.present.incline_pct == base.present.incline_pct     # merged, not replaced
    assert sc.retrieve.too_far_mm == base.retrieve.too_far_mm
    assert sc.adjust == base.adjust
    # naming an adjust algorithm replaces the scenario's params (they were water marks')
    ov = _write(tmp_path / "n.yaml", "adjust:\n  algorithm: none\n")
    sc, _ = load_scenario(LENSES, overlay=ov)
    assert sc.adjust.algorithm == "none" and sc.adjust.params == {}
    assert sc.adjust.period_s == base.adjust.period_s


@pytest.mark.parametrize("text, line, what", [
    ("present:\n  horizontal_mm_s: 150\nadjust:\n  algorthm: none\n", 4, "did you mean"),
    ("present:\n  horizontal_mm_s: 900\n", 2, "max_mm_s 400"),
    ("adjust:\n  algorithm: water_marks\n  params: {low: 5, hgh: 3}\n", 3, "'hgh'"),
])
def test_bad_overlay_names_the_overlay_file_and_line(tmp_path, capsys, text, line, what):
    ov = _write(tmp_path / "bad.yaml", text)
    with pytest.raises(ConfigError) as e:
        load_scenario(LENSES, overlay=ov)
    assert (e.value.file, e.value.line) == (ov, line)
    assert main(["run", LENSES, "--overlay", ov, "--fast", "--no-db"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"feeder: {ov}:{line}: ") and what in err and "\n" not in err


def test_scenario_errors_still_name_the_scenario(tmp_path):
    """A mistake in the scenario itself is not blamed on the overlay."""
    sc = tmp_path / "s.yaml"
    sc.write_text(Path(LENSES).read_text().replace("cell: ../cells/sim.yaml",
                                                   f"cell: {ROOT / 'cells' / 'sim.yaml'}")
                  .replace("policy: fifo", "policy: fiffo"))
    ov = _write(tmp_path / "o.yaml", "present:\n  horizontal_mm_s: 200\n")
    with pytest.raises(ConfigError) as e:
        load_scenario(sc, overlay=ov)
    assert e.value.file == str(sc) and e.value.key == "retrieve.policy"


@pytest.mark.parametrize("space", ["ours", "watermarks", "fixed"])
def test_every_point_of_a_space_is_a_legal_scenario(tmp_path, space):
    """Random points of each space, on both shipped scenarios, pass the loader's checks
    (bounds from the cell's axis limits), so no trial is refused or clamped."""
    import optuna

    from feeder_bt.config.overlay import write_overlay
    from feeder_bt.tuning.space import Limits, suggest
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    for path in (LENSES, SQUARES):
        limits = Limits.of(*load_scenario(path))
        study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=3))
        for _ in range(8):
            trial = study.ask()
            overlay = suggest(trial, space, limits)
            write_overlay(tmp_path / "p.yaml", overlay)
            sc, cell = load_scenario(path, overlay=tmp_path / "p.yaml")
            incline = sc.present.horizontal_mm_s * sc.present.incline_pct / 100
            assert incline <= cell.conveyors["incline"].max_mm_s
            study.tell(trial, 0.0)


# --------------------------------------------------------------------------- the search

@pytest.fixture(scope="module")
def study_file(tmp_path_factory):
    """A two-trial search in this process, then continued to three."""
    d = tmp_path_factory.mktemp("tune")
    db, out = d / "s.db", d / "o.yaml"
    assert main(["tune", LENSES, "--trials", "2", *TINY, *WHOLE, "--workers", "1",
                 "--study", str(db), "--out", str(out)]) == 0
    first = _values(db)
    first_overlay = yaml.safe_load(out.read_text())
    assert main(["tune", LENSES, "--trials", "3", *TINY, *WHOLE, "--workers", "1",
                 "--study", str(db), "--out", str(out)]) == 0
    return db, out, first, first_overlay


def _values(db: Path) -> list[float | None]:
    import optuna
    study = optuna.load_study(study_name="lenses:ours", storage=f"sqlite:///{db}")
    return [t.value for t in study.trials]


def test_study_resumes_and_the_best_only_improves(study_file):
    db, out, first, _ = study_file
    values = _values(db)
    assert len(first) == 2 and len(values) == 3
    assert values[:2] == first                 # the resumed study kept its trials
    assert None not in values                  # none failed: every point was legal
    assert max(values) > 0
    assert max(values) >= max(first)


def test_overlay_out_is_the_best_trial_and_reproduces_it(study_file, tmp_path):
    db, out, _, first_overlay = study_file
    import optuna
    study = optuna.load_study(study_name="lenses:ours", storage=f"sqlite:///{db}")
    best = study.best_trial
    text = out.read_text()
    assert f"trial {best.number}: {best.value:.2f} parts/min" in text
    assert yaml.safe_load(text) == best.user_attrs["overlay"]
    report = run_job(RunOptions(scenario=LENSES, overlay=str(out), duration=20, fast=True,
                                seed=1, view="none", db=None))
    assert report["parts_per_minute"] == pytest.approx(best.value)
    assert first_overlay == study.trials[max(range(2), key=lambda i: study.trials[i].value)
                                         ].user_attrs["overlay"]


def test_a_new_study_starts_from_the_scenario_as_written(study_file, tmp_path):
    """Trial 0 is lenses as shipped (the thesis's water marks, FIFO): its overlay changes
    nothing that matters, and its parts/min is that of a run without an overlay."""
    import dataclasses

    import optuna

    from feeder_bt.config.overlay import write_overlay
    db = study_file[0]
    first = optuna.load_study(study_name="lenses:ours", storage=f"sqlite:///{db}").trials[0]
    assert first.user_attrs["start"] == "scenario"
    write_overlay(tmp_path / "t0.yaml", first.user_attrs["overlay"])
    plain, _ = load_scenario(LENSES)
    tuned, _ = load_scenario(LENSES, overlay=tmp_path / "t0.yaml")
    for part in ("present", "adjust", "locate", "retrieve"):
        a, b = dataclasses.asdict(getattr(plain, part)), dataclasses.asdict(getattr(tuned, part))
        assert {k: v for k, v in b.items() if a.get(k) != v} == {}, part
    report = run_job(RunOptions(scenario=LENSES, duration=20, fast=True, seed=1,
                                view="none", db=None))
    assert report["parts_per_minute"] == pytest.approx(first.value)


def test_where_the_scenario_is_not_a_point_of_the_space_the_search_starts_anywhere(tmp_path):
    from feeder_bt.tuning.space import Limits, start_params
    squares = load_scenario(SQUARES)
    assert start_params(squares[0], "watermarks", Limits.of(*squares)) is None  # no marks
    sc = _write(tmp_path / "fast.yaml", Path(LENSES).read_text().replace(
        "frame_spacing_mm: 300", "frame_spacing_mm: 20").replace(
        "cell: ../cells/sim.yaml", f"cell: {ROOT / 'cells' / 'sim.yaml'}"))
    lenses = load_scenario(sc)
    for space in ("ours", "watermarks", "fixed"):     # every space searches the spacing
        assert start_params(lenses[0], space, Limits.of(*lenses)) is None   # below 0.4 x
    assert start_params(load_scenario(LENSES)[0], "fixed",
                        Limits.of(*load_scenario(LENSES))) is not None


def test_resume_refuses_another_duration(study_file, capsys):
    db = study_file[0]
    assert main(["tune", LENSES, "--trials", "4", "--duration", "25", "--seeds", "1",
                 "--workers", "1", "--study", str(db)]) == 2
    err = capsys.readouterr().err.strip()
    assert "duration_s 20.0, not 25.0" in err and "\n" not in err


def test_progress_lines_when_not_a_terminal(tmp_path, capsys):
    assert main(["tune", LENSES, "--trials", "1", *TINY, "--workers", "1", "--space",
                 "fixed", "--study", str(tmp_path / "f.db")]) == 0
    err = capsys.readouterr().err
    assert "tune: 1 trials on this process" in err
    assert "trial 0 [1/1]: " in err and "parts/min" in err and "none + fifo belt" in err
    assert "(the scenario as written)" in err


def test_report_plots_the_study(study_file, tmp_path, capsys):
    db = study_file[0]
    png = tmp_path / "study.png"
    assert main(["report", "--study", str(db), "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    assert "lenses:ours: 3 trials completed" in out and "best: trial" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "importance: " in out                              # the right-hand panel's
    assert main(["report", "--study", str(tmp_path / "none.db")]) == 2


def test_same_search_on_a_local_dask_cluster(study_file, tmp_path):
    """The search on a Dask cluster (one worker process on 127.0.0.1) draws the same
    points as in this process and gets the same parts/min for them."""
    distributed = pytest.importorskip("distributed")
    db = tmp_path / "d.db"
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  host="127.0.0.1", dashboard_address=None) as cluster:
        assert main(["tune", LENSES, "--trials", "2", *TINY, *WHOLE, "--dask",
                     cluster.scheduler_address, "--study", str(db)]) == 0
    assert _values(db) == study_file[2]


def test_ctrl_c_fails_the_open_trial_without_spending_the_budget(tmp_path, monkeypatch):
    """A run interrupted in a worker ends the search (KeyboardInterrupt); its trial fails
    as interrupted and does not count, so a rerun still does the trials asked for."""
    from feeder_bt.tuning import search
    calls = []

    def fake(job):                      # the second run is the one Ctrl-C reached
        calls.append(job)
        if len(calls) == 2:
            return {"interrupted": True, "error": "interrupted", "seed": job.seed}
        return {"ppm": 50.0 + len(calls), "seed": job.seed}

    monkeypatch.setattr(search, "evaluate", fake)
    cfg = search.TuneConfig(scenario=LENSES, trials=2, duration=20, seeds=1,
                            study=str(tmp_path / "i.db"), halving=False)
    with pytest.raises(KeyboardInterrupt):
        search.run_search(cfg, search.InlineExecutor(), 1)
    study = search.run_search(cfg, search.InlineExecutor(), 1)
    states = [t.state.name for t in study.trials]
    assert states == ["COMPLETE", "FAIL", "COMPLETE"]
    assert study.trials[1].user_attrs["error"] == search.INTERRUPTED
    assert len(search.finished(study)) == 2 and study.best_value == 53.0


def test_a_wear_budget_keeps_the_best_within_it(tmp_path, capsys):
    """--max-recirc R: a trial whose parts recirculated more than R per placed part is
    never the best (nor the overlay written); with no trial within R, one line, exit 2."""
    import optuna
    db, out = tmp_path / "s.db", tmp_path / "o.yaml"
    run = ["tune", LENSES, "--trials", "4", "--duration", "60", "--seeds", "1", "--workers",
           "1", "--study", str(db), *WHOLE, "--max-recirc", "off"]
    assert main(run) == 0
    trials = optuna.load_study(study_name="lenses:ours", storage=f"sqlite:///{db}").trials
    recirc = {t.number: t.user_attrs["recirc_per_placed"] for t in trials
              if t.user_attrs.get("recirc_per_placed") is not None}
    frugal = min(recirc, key=recirc.get)
    greedy = max(trials, key=lambda t: t.value).number
    assert recirc[frugal] > 0 and greedy != frugal         # the budget has a choice to make
    budget = recirc[frugal] + 1e-4                         # only the frugal trial is within
    capsys.readouterr()
    assert main([*run, "--max-recirc", f"{budget:.6f}", "--out", str(out)]) == 0
    said = capsys.readouterr().out
    assert f"best: trial {frugal}," in said and "recirculated" in said
    assert yaml.safe_load(out.read_text()) == trials[frugal].user_attrs["overlay"]
    assert main([*run, "--max-recirc", f"{recirc[frugal] / 2:.6f}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("feeder: study") and "no trial within --max-recirc" in err
    with pytest.raises(SystemExit) as e:                   # argparse's usage line
        main(["tune", LENSES, "--max-recirc", "-1"])
    assert e.value.code == 2 and "--max-recirc" in capsys.readouterr().err


def test_baselines_search_every_pick_policy_and_frame_spacing():
    """A baseline gets every option ours gets but belt control."""
    import optuna

    from feeder_bt.tuning.space import Limits, suggest
    sc = load_scenario(LENSES)
    lim = Limits.of(*sc)
    for space in ("watermarks", "fixed"):
        study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=1))
        seen = set()
        for _ in range(40):
            trial = study.ask()
            overlay = suggest(trial, space, lim)
            seen.add(overlay["retrieve"]["policy"])
            assert 0.4 * lim.frame_spacing_mm <= overlay["locate"]["frame_spacing_mm"]
            study.tell(trial, 0.0)
        assert seen == {"fifo", "earliest_deadline", "shortest_cycle", "lookahead"}, space


def test_a_grid_over_the_fixed_speeds_runs_each_point_once(tmp_path, capsys):
    """--grid: the fixed space's two speeds (k levels each) by every policy, within the
    trial budget; a resumed study runs the points not yet run, none twice."""
    import optuna
    db = tmp_path / "g.db"
    run = ["tune", LENSES, "--space", "fixed", "--grid", *TINY, "--workers", "1",
           "--study", str(db)]
    assert main([*run, "--trials", "16"]) == 0
    assert main([*run, "--trials", "20"]) == 0                # the grid is done: no more
    trials = optuna.load_study(study_name="lenses:fixed:grid",
                               storage=f"sqlite:///{db}").get_trials()
    points = [(t.params["belt_mm_s"], t.params["incline_mm_s"], t.params["policy"])
              for t in trials if t.state.name == "COMPLETE"]
    assert len(points) == len(set(points)) == 16          # 2 x 2 speeds x 4 policies
    assert {p[0] for p in points} == {50.0, 400.0}
    capsys.readouterr()
    assert main(["tune", LENSES, "--space", "ours", "--grid", "--study",
                 str(tmp_path / "x.db")]) == 2
    assert "--grid searches the fixed space" in capsys.readouterr().err
    assert main([*run, "--trials", "8", "--study", str(tmp_path / "y.db")]) == 2
    assert "--grid needs --trials 16 at least" in capsys.readouterr().err


def test_a_kit_scenario_is_tuned_for_kits_per_minute(tmp_path, capsys):
    """A part that completes no kit is worth nothing to an assembly: a scenario with
    ``retrieve.kit`` is searched for kits/min (the report's kits.per_minute), and says so."""
    import optuna
    db = tmp_path / "k.db"
    kits = str(ROOT / "scenarios" / "kits_lenses_squares.yaml")
    assert main(["tune", kits, "--trials", "2", "--duration", "120", "--seeds", "1",
                 "--workers", "1", "--study", str(db)]) == 0
    said = capsys.readouterr().out
    assert "kits/min" in said and "parts/min" not in said.split("best:")[1]
    study = optuna.load_study(study_name="kits_lenses_squares:ours", storage=f"sqlite:///{db}")
    assert study.user_attrs["unit"] == "kits/min"
    from feeder_bt.config.overlay import write_overlay
    best = study.best_trial
    write_overlay(tmp_path / "o.yaml", best.user_attrs["overlay"])
    r = run_job(RunOptions(scenario=kits, duration=120.0, fast=True, seed=1, view="none",
                           db=None, overlay=str(tmp_path / "o.yaml")))
    assert best.value == pytest.approx(r["kits"]["per_minute"])
    assert best.value < r["parts_per_minute"] / 3        # four parts a kit, not one
    # a study of parts/min is not continued as one of kits/min
    search_cfg = ["tune", kits, "--trials", "3", "--duration", "120", "--seeds", "1",
                  "--workers", "1", "--study", str(db)]
    study.set_user_attr("unit", "parts/min")
    assert main(search_cfg) == 2
    assert "unit" in capsys.readouterr().err


# --------------------------------------------------------------------------- short trials first

def _fake_runs(monkeypatch, clock=None):
    """``search.evaluate`` replaced by a deterministic function of the setting: parts/min
    rise with the belt speed and the wear with the incline speed (over the budget above
    about 110 mm/s); a run of a quarter duration reads lower, as a short run's start-up
    does. ``clock``: a list whose first item each run advances by the run's length / 100."""
    from feeder_bt.tuning import search
    jobs = []

    def fake(job):
        jobs.append(job)
        if clock is not None:
            clock[0] += job.duration / 100.0
        p = job.overlay["present"]
        belt = p["horizontal_mm_s"]
        incline = belt * p["incline_pct"] / 100.0
        short = 0.8 if job.duration < 20 else 1.0
        return {"ppm": round(short * (40 + belt / 20 + job.seed / 10), 3), "seed": job.seed,
                "recirc_per_placed": round(incline / 75.0, 3)}

    monkeypatch.setattr(search, "evaluate", fake)
    return jobs


def test_halving_runs_short_trials_first_and_the_best_is_a_whole_one(tmp_path, monkeypatch):
    """A quarter run on seed 1, then the whole run, then the other seeds; most trials stop
    at the first rung, and the best within the budget is a trial that ran every rung."""
    from optuna.trial import TrialState

    from feeder_bt.tuning import search
    jobs = _fake_runs(monkeypatch)
    cfg = search.TuneConfig(scenario=LENSES, trials=24, duration=20, seeds=2, space="fixed",
                            study=None, max_recirc=1.5, sampler_seed=3, halving=True)
    assert search.rungs(cfg) == [(5.0, (1,)), (20.0, (1,)), (20.0, (2,))]
    study = search.run_search(cfg, search.InlineExecutor(), 1)
    states = [t.state for t in study.trials]
    assert len(states) == 24 and states.count(TrialState.PRUNED) >= 8
    assert sum(j.duration == 5.0 for j in jobs) == 24          # every trial's first rung
    assert sum(j.duration == 20.0 for j in jobs) < 2 * 24      # whole runs: fewer than 24 x 2
    for t in study.trials:
        if t.state is TrialState.COMPLETE:          # its value: the whole runs, both seeds
            assert len(t.user_attrs["per_seed_ppm"]) == 2
    _, best = search.best_overlay(study, 1.5)
    assert best.state is TrialState.COMPLETE and best.user_attrs["recirc_per_placed"] <= 1.5
    whole = [t for t in study.trials if t.state is TrialState.COMPLETE
             and t.user_attrs["recirc_per_placed"] <= 1.5]
    assert best.value == max(t.value for t in whole)
    # the same search again: the same trials (a seeded sampler, one worker)
    again = search.run_search(cfg, search.InlineExecutor(), 1)
    assert [t.params for t in again.trials] == [t.params for t in study.trials]


def test_a_rung_keeps_the_best_third_and_the_budget_ranks_first():
    from feeder_bt.tuning.search import promoted, score
    assert promoted(5.0, [5.0], 3)                      # the first is the best so far
    assert not promoted(4.0, [5.0, 4.0], 3)             # fewer than 2 x eta: the best only
    scores = [9.0, 8.0, 7.0, 6.0, 5.0, 4.0]
    assert promoted(8.0, scores, 3) and not promoted(7.0, scores, 3)   # the best 6 // 3
    assert score(70.0, 1.4, 1.5) == 70.0
    assert score(90.0, 2.0, 1.5) == -0.5 < score(1.0, 0.2, 1.5)       # over: below any within
    assert score(90.0, 2.0, None) == 90.0


def test_a_wall_clock_budget_stops_starting_runs(tmp_path, monkeypatch):
    """--minutes M: no run starts that would end after M minutes of the command (here a
    clock each run moves on, and the command began 20 s before the search), less the
    wrap-up's reserve; trials cut short are pruned, and the search ends with the trials it
    finished."""
    from optuna.trial import TrialState

    from feeder_bt.tuning import search
    clock = [20.0]
    _fake_runs(monkeypatch, clock)
    monkeypatch.setattr(search.time, "monotonic", lambda: clock[0])
    cfg = search.TuneConfig(scenario=LENSES, trials=1000, duration=600, seeds=2,
                            space="fixed", study=None, max_recirc=1.5, minutes=2.0,
                            halving=True, started=0.0)
    study = search.run_search(cfg, search.InlineExecutor(), 1)
    assert 5 <= len(study.trials) < 1000
    assert all(t.state in (TrialState.COMPLETE, TrialState.PRUNED) for t in study.trials)
    assert clock[0] <= 120.0 - search.WRAP_UP_S         # the last run ended in time


def test_the_wear_budget_is_on_by_default(tmp_path, capsys):
    """Unless told otherwise, `feeder tune` keeps 1.5 recirculations per placed part;
    'off' searches without; the report names the budget its best is within."""
    from feeder_bt.cli.tune import _budget
    from feeder_bt.tuning.search import DEFAULT_MAX_RECIRC
    assert DEFAULT_MAX_RECIRC == 1.5
    assert _budget("off") is None and _budget("2") == 2.0
    db = tmp_path / "b.db"
    assert main(["tune", LENSES, "--trials", "1", "--duration", "60", "--seeds", "1",
                 "--workers", "1", "--study", str(db)]) == 0
    assert main(["report", "--study", str(db)]) == 0
    out = capsys.readouterr().out
    assert "best (within 1.5 recirculations per placed part): trial 0" in out


def test_importance_is_printed_only_with_enough_trials(study_file, capsys):
    """Three trials: PED-ANOVA's best 10 % would be less than one trial, so no importance
    is shown, and the report says why."""
    from feeder_bt.tuning.report import MIN_IMPORTANCE_TRIALS
    assert main(["report", "--study", str(study_file[0])]) == 0
    out = capsys.readouterr().out
    assert (f"importance: not shown, 3 completed trials (PED-ANOVA judges by the best 10 %, "
            f"which should hold 5 trials: {MIN_IMPORTANCE_TRIALS} at least)") in out
