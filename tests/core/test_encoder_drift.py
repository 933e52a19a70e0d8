"""The in-run re-check of the two belt counters: ``DriftWatch`` on
cached reads of different ages, and a whole run whose robot counter slips on purpose."""

from __future__ import annotations

import re

import pytest

from feeder_bt.app.run import RunOptions, run_job
from feeder_bt.core.encoder import DriftWatch, EncoderSync, wrap
from feeder_bt.core.errors import ConfigError

CPM = 20.0


def _watch(window: int = 5) -> tuple[EncoderSync, DriftWatch]:
    sync = EncoderSync(32, 24)
    sync.reset(1000, 5_000)
    return sync, DriftWatch(sync, CPM, window=window, max_age_s=0.25)


def _run_belt(watch: DriftWatch, slip_counts: int, speed_mm_s: float = 300.0,
              n: int = 20, ages: tuple[float, float] = (0.05, 0.002)) -> list[float | None]:
    """A belt at constant speed; the Galil count read ``ages[0]`` ago, the robot's ``ages[1]``
    ago (different moments: the check must carry one forward to the other)."""
    out = []
    for i in range(1, n + 1):
        now = float(i)
        t_g, t_r = now - ages[0], now - ages[1]
        g = 1000 + round(t_g * speed_mm_s * CPM)
        r = wrap(5_000 + slip_counts + round(t_r * speed_mm_s * CPM), 24)
        out.append(watch.sample(now, g, ages[0], r, ages[1]))
    return out


def test_reads_of_different_ages_on_a_moving_belt_are_no_drift():
    _, watch = _watch()
    got = [d for d in _run_belt(watch, 0) if d is not None]
    assert got and all(abs(d) < 0.1 for d in got)


def test_a_slipped_counter_is_measured_in_mm():
    _, watch = _watch()
    got = [d for d in _run_belt(watch, 200) if d is not None]
    assert got[-1] == pytest.approx(10.0, abs=0.1)        # 200 counts at 20 counts/mm



def _verdicts(watch: DriftWatch, offsets_mm: list[float], limit_mm: float = 3.0
              ) -> list[bool]:
    """Feed one sample per offset (the robot's count ahead by that many mm) and return,
    for each verdict, whether the watch calls for a fault."""
    out = []
    for i, off in enumerate(offsets_mm, start=1):
        now = float(i)
        g = 1000 + round(now * 300 * CPM)
        r = wrap(5_000 + round((now * 300 + off) * CPM), 24)
        d = watch.sample(now, g, 0.0, r, 0.0)
        if d is not None:
            out.append(watch.held_past(d, limit_mm))
    return out


def test_a_burst_of_late_stamps_is_no_fault():
    """Emulated runs through a slow hop read bursts like this one (+4..5 mm on six reads
    of eleven): medians pass the 3 mm limit for a few verdicts, then fall back."""
    _, watch = _watch(window=9)
    burst = [0.5] * 10 + [4.8, 0.6, 4.9, 4.0, 0.5, 3.3, 4.1, 0.4, 4.7, 0.7, 4.2] + [0.5] * 10
    verdicts = _verdicts(watch, burst)
    assert watch.max_abs_mm > 3.0                 # the medians did pass the limit
    assert not any(verdicts)


def test_a_step_past_the_limit_faults_after_a_window_and_twice_the_limit_at_once():
    _, watch = _watch(window=9)
    # verdict k is sample 10 + k (the first sample has no speed yet, then a window of 9);
    # the step comes at sample 11, and the median shows it at sample 15 (verdict 5)
    verdicts = _verdicts(watch, [0.0] * 10 + [4.0] * 30)
    assert verdicts.index(True) == 5 + 9 - 1              # held for a window of verdicts
    _, watch = _watch(window=9)
    verdicts = _verdicts(watch, [0.0] * 10 + [7.0] * 10)
    assert verdicts.index(True) == 5                      # twice the limit: at once


def test_without_age_compensation_a_stale_read_would_look_like_drift():
    """The counterfactual the compensation exists for: 48 ms of age difference at 300 mm/s
    is 14 mm; a watch told both reads are fresh reports it as drift."""
    _, watch = _watch()
    for i in range(1, 12):
        now = float(i)
        g = 1000 + round((now - 0.048) * 300 * CPM)
        r = 5_000 + round(now * 300 * CPM)
        d = watch.sample(now, g, 0.0, r, 0.0)
    assert d == pytest.approx(14.4, abs=0.2)


def test_stale_or_missing_reads_give_no_sample():
    _, watch = _watch(window=1)
    assert watch.sample(1.0, 0, None, 0, 0.0) is None          # link down
    assert watch.sample(2.0, 0, 0.0, 0, 5.0) is None           # poller stalled
    assert watch.taken == 0


def test_reads_whose_moment_is_in_doubt_give_no_sample():
    """A host slow to hear its replies: 20 ms of round trip at 300 mm/s leaves 3 mm of
    doubt about when a count was sampled, so the pair is left out (counted), not read as
    drift; reads that came back in 2 ms are taken."""
    _, watch = _watch(window=1)
    for i in range(1, 6):
        now = float(i)
        g = 1000 + round((now - 0.01) * 300 * CPM)      # stamped 10 ms after it was sampled
        r = 5_000 + round(now * 300 * CPM)
        assert watch.sample(now, g, 0.0, r, 0.0, doubt_s=0.02) is None
    assert watch.taken == 0 and watch.doubtful >= 4
    for i in range(6, 9):
        now = float(i)
        g = 1000 + round(now * 300 * CPM)
        r = 5_000 + round(now * 300 * CPM)
        d = watch.sample(now, g, 0.0, r, 0.0, doubt_s=0.001)
    assert d is not None and abs(d) < 0.1


def test_the_robot_counter_wrapping_is_not_drift():
    sync = EncoderSync(32, 24)
    sync.reset(0, 2 ** 23 - 50)                                # robot wraps within a second
    watch = DriftWatch(sync, CPM, window=3)
    got = []
    for i in range(1, 8):
        g = i * 6000
        got.append(watch.sample(float(i), g, 0.0, wrap(2 ** 23 - 50 + g, 24), 0.0))
    assert [d for d in got if d is not None] == [0.0] * 4


SLIP = """\
seed: 1
scripted:
  - {at_s: 60, kind: encoder_slip, counts: 200}
"""


def test_a_slipping_robot_counter_faults_the_run_within_seconds(tmp_path):
    plan = tmp_path / "slip.yaml"
    plan.write_text(SLIP)
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", duration=180.0, fast=True,
                           seed=1, view="none", faults=str(plan)))
    assert r["state"] == "FAULT"
    got = re.search(r"belt encoders disagree by \+([\d.]+) mm", r["fault"])
    # 200 counts; the robot's count is a sample held for 16 ms, so one reading is off by up
    # to half a cycle of belt travel (2.4 mm at 300 mm/s) and the median of 9 by less
    assert got and float(got.group(1)) == pytest.approx(10.0, abs=1.6)
    assert r["faults"].get("encoder_drift") == 1
    assert r["sim_seconds"] < 75                              # slip at 60 s, window of 9 s
    assert r["encoder_drift"]["max_abs_mm"] == pytest.approx(10.0, abs=1.6)
    assert r["parts"]["lost"] == 0


def test_a_clean_run_sees_no_drift():
    r = run_job(RunOptions(scenario="scenarios/lenses.yaml", duration=90.0, fast=True,
                           seed=1, view="none"))
    assert r["state"] == "STOPPED"
    assert r["encoder_drift"]["samples"] > 60
    assert r["encoder_drift"]["max_abs_mm"] < 1.0            # below the warning level


def test_a_warning_above_the_limit_is_refused(tmp_path):
    from feeder_bt.config.loader import load_cell
    text = open("cells/sim.yaml").read()
    assert "\nencoder:" in text
    cell = tmp_path / "c.yaml"
    cell.write_text(text.replace("\nencoder:", "\nencoder:\n  drift_warn_mm: 5\n", 1))
    with pytest.raises(ConfigError, match="drift_warn_mm"):
        load_cell(cell)
