"""``feeder report --study FILE.db``: what a ``feeder tune`` search found — every study in
the file summarised, and ``--plot`` drawing parts/min per trial (with the best so far) and
the parameters' importance (Optuna's PED-ANOVA, no scikit-learn needed) for each study."""

from __future__ import annotations

import sqlite3
from pathlib import Path
from typing import Any

from feeder_bt.core.errors import FeederError
from feeder_bt.tuning.search import unit_of


class StudyError(FeederError):
    exit_code = 2


def load_studies(path: str | Path) -> list[Any]:
    """Every Optuna study in ``path``; a missing file or one without studies is one line."""
    p = Path(path)
    if not p.is_file():
        raise StudyError(f"{p}: no such study file")
    try:
        with sqlite3.connect(f"file:{p}?mode=ro", uri=True) as conn:
            conn.execute("SELECT study_name FROM studies").fetchall()
    except sqlite3.Error:
        raise StudyError(f"{p}: not a `feeder tune` study file (no Optuna studies in it)"
                         ) from None
    import optuna
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = f"sqlite:///{p.resolve()}"
    names = [s.study_name for s in optuna.get_all_study_summaries(storage,
                                                                  include_best_trial=False)]
    if not names:
        raise StudyError(f"{p}: holds no study yet")
    return [optuna.load_study(study_name=n, storage=storage) for n in names]


#: completed trials before an importance is printed: PED-ANOVA judges a parameter by how
#: the best 10 % of the trials spread in it against all of them, and Optuna advises at least
#: 5 trials in that best 10 % (its PedAnovaImportanceEvaluator's notes); with fewer, the
#: "best 10 %" is a trial or two, and whatever they happen to differ in looks important
MIN_IMPORTANCE_TRIALS = 50


def importance_note(study: Any) -> str | None:
    """Why no importance is given for ``study`` (None: it is)."""
    from optuna.trial import TrialState
    n = len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)))
    if n < MIN_IMPORTANCE_TRIALS:
        return (f"importance: not shown, {n} completed trials (PED-ANOVA judges by the best "
                f"10 %, which should hold 5 trials: {MIN_IMPORTANCE_TRIALS} at least)")
    return None


def importances(study: Any) -> dict[str, float]:
    """Parameter importance (PED-ANOVA) over the completed trials (pruned ones ran shorter:
    their scores are not values); empty with fewer than ``MIN_IMPORTANCE_TRIALS`` or when
    the parameters never varied."""
    import warnings

    from optuna.importance import PedAnovaImportanceEvaluator, get_param_importances
    from optuna.trial import TrialState
    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if len(done) < MIN_IMPORTANCE_TRIALS:
        return {}
    # the parameters every trial has (an adjuster's own exist only in its trials)
    shared = sorted(set.intersection(*(set(t.params) for t in done)))
    if not shared:
        return {}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return dict(get_param_importances(
                study, evaluator=PedAnovaImportanceEvaluator(), params=shared))
    except (RuntimeError, ValueError, ZeroDivisionError):
        return {}


def summary_lines(study: Any) -> list[str]:
    from optuna.trial import TrialState

    from feeder_bt.tuning.search import TuneError, best_overlay, describe
    trials = study.get_trials(deepcopy=False)
    done = [t for t in trials if t.state is TrialState.COMPLETE]
    failed = sum(t.state is TrialState.FAIL for t in trials)
    pruned = sum(t.state is TrialState.PRUNED for t in trials)
    a = study.user_attrs
    head = (f"{study.study_name}: {len(done)} trials completed"
            + (f", {pruned} pruned (successive halving)" if pruned else "")
            + f", {failed} failed; {a.get('duration_s', '?')} s x {a.get('seeds', '?')} "
              f"seeds each")
    if not done:
        return [head]
    budget = a.get("max_recirc")
    try:
        _, best = best_overlay(study, budget)
    except TuneError:
        return [head, f"  best: no trial within the wear budget of {budget:g} "
                      f"recirculations per placed part"]
    within = f" (within {budget:g} recirculations per placed part)" if budget is not None \
        else ""
    lines = [head, f"  best{within}: trial {best.number}, {best.value:.2f} "
                   f"{unit_of(study)}: {describe(best.user_attrs.get('overlay', {}))}"]
    imp = importances(study)
    if imp:
        lines.append("  importance: " + ", ".join(f"{k} {v:.2f}" for k, v in imp.items()))
    else:
        lines.append("  " + (importance_note(study) or "importance: none (no parameter "
                                                        "every trial has varied)"))
    return lines


def plot_studies(studies: list[Any]) -> Any:
    """One row per study: parts/min per trial with the best so far, and the importances."""
    from matplotlib.figure import Figure
    from matplotlib.ticker import MaxNLocator
    from optuna.trial import TrialState

    fig = Figure(figsize=(11, 3.6 * len(studies)), layout="constrained")
    axes = fig.subplots(len(studies), 2, squeeze=False)
    for (ax_t, ax_i), study in zip(axes, studies, strict=True):
        done = [t for t in study.get_trials(deepcopy=False) if t.state is TrialState.COMPLETE]
        xs = [t.number for t in done]
        ys = [t.value for t in done]
        ax_t.scatter(xs, ys, s=18, color="tab:blue", label="trial (mean over seeds)")
        best, run = [], float("-inf")
        for y in ys:
            run = max(run, y)
            best.append(run)
        ax_t.step(xs, best, where="post", color="tab:green", label="best so far")
        ceilings = [t.user_attrs.get("ceiling_ppm") for t in done]
        if ceilings and all(ceilings):
            ax_t.axhline(max(ceilings), color="grey", linestyle="--", linewidth=1,
                         label=f"ceiling ({max(ceilings):.1f})")
        ax_t.set_title(f"{study.study_name}: {unit_of(study)} per trial")
        ax_t.set_xlabel("trial")
        ax_t.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax_t.set_ylabel(unit_of(study))
        ax_t.grid(True, alpha=0.3)
        ax_t.legend(loc="best", fontsize="small")
        imp = importances(study)
        names = list(imp)[::-1]
        ax_i.barh(names, [imp[n] for n in names], color="tab:orange")
        ax_i.set_title("parameter importance (PED-ANOVA)")
        ax_i.set_xlabel("importance (normalised to sum 1)")
        if not imp:
            ax_i.text(0.5, 0.5, f"not shown: needs {MIN_IMPORTANCE_TRIALS} completed trials",
                      ha="center", transform=ax_i.transAxes)
    return fig


def report_study(path: str, plot: str | None) -> int:
    """Print each study's summary; with ``plot``, write the figure there."""
    studies = load_studies(path)
    for study in studies:
        for line in summary_lines(study):
            print(line)
    if plot:
        fig = plot_studies(studies)
        try:
            Path(plot).parent.mkdir(parents=True, exist_ok=True)
            fig.savefig(plot, dpi=100)
        except (OSError, ValueError) as e:
            raise StudyError(f"cannot write {plot}: {e}") from None
        print(f"plot: {plot}")
    return 0
