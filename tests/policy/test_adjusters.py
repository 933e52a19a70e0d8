"""Auto-adjusters (thesis 8.1.3): registry, parameter checks, each algorithm step by step."""

from __future__ import annotations

import dataclasses

import pytest

from feeder_bt.policy.adjusters import (
    ADJUSTERS,
    Adjuster,
    AdjusterParamError,
    AdjustInputs,
    NoAdjuster,
    QueueProportional,
    Speeds,
    WaterMarks,
    make_adjuster,
)


def inp(queue_len: int, horizontal: float, t: float = 0.0) -> AdjustInputs:
    return AdjustInputs(t=t, queue_len=queue_len, horizontal_mm_s=horizontal,
                        incline_pct=40.0, robot_speed_pct=80.0, retrieved=3, located=9,
                        recirculated=2, missed=1)


def run(adj: Adjuster, queue_lens: list[int], start: float) -> list[float]:
    """Feed each output speed back in as the next current speed, as the adjust tree does."""
    speed, out = start, []
    for i, q in enumerate(queue_lens):
        speed = adj.update(inp(q, speed, t=0.5 * i)).horizontal_mm_s
        out.append(speed)
    return out


# ---------------------------------------------------------------------------- registry


def test_registry_holds_the_three_algorithms():
    assert ADJUSTERS["none"] is NoAdjuster
    assert ADJUSTERS["queue_proportional"] is QueueProportional
    assert ADJUSTERS["water_marks"] is WaterMarks
    assert isinstance(make_adjuster("water_marks", {}), WaterMarks)


def test_scenario_default_algorithm_is_registered():
    from feeder_bt.core.model import AdjustParams

    assert AdjustParams().algorithm in ADJUSTERS


def test_unknown_algorithm_is_a_value_error_naming_it():
    with pytest.raises(ValueError, match="'fuzzy'") as err:
        make_adjuster("fuzzy", {})
    assert "water_marks" in str(err.value)   # lists what is known


@pytest.mark.parametrize("name", ["none", "queue_proportional", "water_marks"])
def test_unknown_param_is_a_value_error_naming_the_key(name):
    with pytest.raises(ValueError, match="hihg") as err:
        make_adjuster(name, {"hihg": 3.0})
    assert isinstance(err.value, AdjusterParamError)
    assert err.value.key == "hihg"


@pytest.mark.parametrize("bad", ["fast", None, True, float("nan"), float("inf")])
def test_non_numeric_param_is_rejected(bad):
    with pytest.raises(ValueError, match="gain") as err:
        make_adjuster("water_marks", {"gain": bad})
    assert err.value.key == "gain"


def test_params_declare_names_and_defaults():
    assert set(QueueProportional.PARAMS) == {"target", "gain", "min_mm_s", "max_mm_s",
                                             "nominal_mm_s"}
    assert set(WaterMarks.PARAMS) == {"high", "low", "gain", "step", "min_mm_s",
                                      "max_mm_s", "median_mm_s"}
    assert NoAdjuster.PARAMS == {}
    # the thesis's Figure 8-3 settings are the defaults
    assert {k: WaterMarks.PARAMS[k] for k in ("high", "low", "gain", "step")} == {
        "high": 100.0, "low": 50.0, "gain": 0.1, "step": 5.0}


def test_given_params_override_defaults_and_become_floats():
    adj = make_adjuster("water_marks", {"step": 2})
    assert adj.params["step"] == 2.0
    assert isinstance(adj.params["step"], float)
    assert adj.params["high"] == WaterMarks.PARAMS["high"]
    # the class defaults are not mutated by an instance
    assert WaterMarks.PARAMS["step"] == 5.0


def test_params_none_means_defaults():
    assert make_adjuster("queue_proportional", None).params == QueueProportional.PARAMS


@pytest.mark.parametrize(
    ("name", "params", "key"),
    [
        ("queue_proportional", {"min_mm_s": 300.0, "max_mm_s": 100.0}, "min_mm_s"),
        ("queue_proportional", {"min_mm_s": -1.0}, "min_mm_s"),
        ("water_marks", {"low": 60.0, "high": 40.0}, "low"),
        ("water_marks", {"gain": 1.5}, "gain"),
        ("water_marks", {"gain": -0.1}, "gain"),
        ("water_marks", {"step": -5.0}, "step"),
        ("water_marks", {"median_mm_s": 400.0}, "median_mm_s"),
        ("water_marks", {"median_mm_s": 10.0}, "median_mm_s"),
    ],
)
def test_impossible_combinations_are_rejected(name, params, key):
    with pytest.raises(ValueError) as err:
        make_adjuster(name, params)
    assert err.value.key == key


def test_base_class_update_is_abstract():
    with pytest.raises(NotImplementedError):
        Adjuster().update(inp(0, 100.0))


# ---------------------------------------------------------------------------- none


def test_none_returns_speeds_unchanged():
    adj = make_adjuster("none", {})
    for q in (0, 10, 1000):
        assert adj.update(inp(q, 123.5)) == Speeds(123.5, 40.0, 80.0)


# ---------------------------------------------------------------------------- queue_proportional


QP = {"target": 10.0, "gain": 4.0, "min_mm_s": 60.0, "max_mm_s": 250.0,
      "nominal_mm_s": 150.0}


def test_queue_proportional_step_by_step():
    adj = make_adjuster("queue_proportional", QP)
    # speed depends on the queue only, not on the current speed
    assert adj.update(inp(10, 999.0)).horizontal_mm_s == 150.0
    assert adj.update(inp(5, 70.0)).horizontal_mm_s == 170.0
    assert adj.update(inp(15, 70.0)).horizontal_mm_s == 130.0
    assert adj.update(inp(0, 150.0)).horizontal_mm_s == 190.0
    assert adj.update(inp(32, 150.0)).horizontal_mm_s == 62.0


def test_queue_proportional_clamps_both_ends():
    adj = make_adjuster("queue_proportional", QP)
    assert adj.update(inp(40, 150.0)).horizontal_mm_s == 60.0     # 150 - 120 -> min
    assert adj.update(inp(1000, 150.0)).horizontal_mm_s == 60.0
    assert adj.update(inp(0, 150.0)).horizontal_mm_s == 190.0
    wide = make_adjuster("queue_proportional", {**QP, "target": 40.0})
    assert wide.update(inp(0, 150.0)).horizontal_mm_s == 250.0    # 150 + 160 -> max


def test_queue_proportional_passes_incline_and_robot_through():
    adj = make_adjuster("queue_proportional", QP)
    out = adj.update(inp(3, 100.0))
    assert (out.incline_pct, out.robot_speed_pct) == (40.0, 80.0)


def test_queue_proportional_defaults():
    adj = make_adjuster("queue_proportional", {})
    # 150 + 5 * (10 - 4)
    assert adj.update(inp(4, 0.0)).horizontal_mm_s == 180.0


# ---------------------------------------------------------------------------- water_marks


WM = {"high": 20.0, "low": 5.0, "gain": 0.5, "step": 10.0, "min_mm_s": 60.0,
      "max_mm_s": 200.0, "median_mm_s": 120.0}


def test_water_marks_above_high_steps_down_to_min():
    adj = make_adjuster("water_marks", WM)
    assert run(adj, [21] * 6, start=105.0) == [95.0, 85.0, 75.0, 65.0, 60.0, 60.0]


def test_water_marks_below_low_steps_up_to_max():
    adj = make_adjuster("water_marks", WM)
    assert run(adj, [4] * 4, start=175.0) == [185.0, 195.0, 200.0, 200.0]


def test_water_marks_pull_from_above_median():
    adj = make_adjuster("water_marks", WM)
    # halfway to 120 each time: 200 -> 160 -> 140 -> 130
    assert run(adj, [10, 10, 10], start=200.0) == [160.0, 140.0, 130.0]


def test_water_marks_pull_from_below_median():
    adj = make_adjuster("water_marks", WM)
    assert run(adj, [10, 10, 10], start=60.0) == [90.0, 105.0, 112.5]


def test_water_marks_at_median_stays():
    adj = make_adjuster("water_marks", WM)
    assert run(adj, [10, 10], start=120.0) == [120.0, 120.0]


def test_water_marks_marks_themselves_count_as_between():
    adj = make_adjuster("water_marks", WM)
    assert adj.update(inp(20, 200.0)).horizontal_mm_s == 160.0   # == high: pull
    assert adj.update(inp(5, 60.0)).horizontal_mm_s == 90.0      # == low: pull


def test_water_marks_mixed_sequence():
    adj = make_adjuster("water_marks", WM)
    queue = [30, 30, 10, 2, 2, 10, 25]
    #        down down pull  up   up  pull down
    assert run(adj, queue, start=120.0) == [110.0, 100.0, 110.0, 120.0, 130.0, 125.0, 115.0]


def test_water_marks_thesis_settings():
    adj = make_adjuster("water_marks", {"median_mm_s": 150.0})
    assert adj.update(inp(101, 150.0)).horizontal_mm_s == 145.0
    assert adj.update(inp(49, 150.0)).horizontal_mm_s == 155.0
    assert adj.update(inp(75, 250.0)).horizontal_mm_s == 240.0    # 250 - 0.1 * 100
    assert adj.update(inp(75, 50.0)).horizontal_mm_s == 60.0      # 50 + 0.1 * 100


def test_water_marks_output_is_clamped_even_from_outside_the_range():
    adj = make_adjuster("water_marks", WM)
    assert adj.update(inp(30, 40.0)).horizontal_mm_s == 60.0      # below min, slowing
    assert adj.update(inp(0, 500.0)).horizontal_mm_s == 200.0     # above max, speeding up
    assert adj.update(inp(10, 500.0)).horizontal_mm_s == 200.0    # pull lands above max


def test_water_marks_gain_zero_holds_and_one_snaps():
    hold = make_adjuster("water_marks", {**WM, "gain": 0.0})
    snap = make_adjuster("water_marks", {**WM, "gain": 1.0})
    assert hold.update(inp(10, 170.0)).horizontal_mm_s == 170.0
    assert snap.update(inp(10, 170.0)).horizontal_mm_s == 120.0
    assert snap.update(inp(10, 70.0)).horizontal_mm_s == 120.0


def test_water_marks_changes_only_horizontal():
    adj = make_adjuster("water_marks", WM)
    for q in (0, 10, 50):
        out = adj.update(inp(q, 100.0))
        assert (out.incline_pct, out.robot_speed_pct) == (40.0, 80.0)


def test_inputs_are_not_mutated():
    adj = make_adjuster("water_marks", WM)
    i = inp(30, 100.0)
    before = dataclasses.replace(i)
    adj.update(i)
    assert i == before
