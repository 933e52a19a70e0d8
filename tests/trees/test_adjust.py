"""Tick-level tests of the adjust tree."""

from __future__ import annotations

from py_trees.common import Status

from feeder_bt.policy.adjusters import make_adjuster
from feeder_bt.trees import adjust
from tests.support.treeutil import bb_get, make_ctx, part, tick


def run_until_sample(ctx, root, limit: int = 200) -> float:
    """Tick at 50 Hz until the first timeline sample; return the clock time of that tick."""
    for _ in range(limit):
        t = ctx.clock.now()
        tick(root, ctx)
        if ctx.stats.timeline:
            return t
    raise AssertionError("the adjuster never ran")


def test_nothing_happens_before_the_period():
    ctx = make_ctx()
    root = adjust.build(ctx)
    period = ctx.scenario.adjust.period_s
    assert period == 0.5
    while ctx.clock.now() < period - 0.03:
        assert tick(root, ctx) is Status.RUNNING
        assert bb_get("/speeds/horizontal_mm_s") == 150.0
        assert ctx.stats.timeline == []


def test_water_marks_speeds_up_when_queue_is_below_low():
    ctx = make_ctx()
    root = adjust.build(ctx)
    p = ctx.scenario.adjust.params
    assert ctx.scenario.adjust.algorithm == "water_marks" and len(ctx.queue) < p["low"]
    t = run_until_sample(ctx, root)
    assert abs(t - 0.5) < 0.02 + 1e-9
    assert bb_get("/speeds/horizontal_mm_s") == 150.0 + p["step"]
    assert bb_get("/speeds/incline_pct") == 40.0
    assert bb_get("/speeds/robot_speed_pct") == 100.0
    (sample,) = ctx.stats.timeline
    assert sample["horizontal_mm_s"] == 155.0
    assert sample["queue"] == 0
    assert sample["t"] == t
    assert ctx.hal.calls == []                 # the adjuster only writes the blackboard


def test_water_marks_slows_down_when_queue_is_above_high():
    ctx = make_ctx(adjust={"params": {"high": 3, "low": 1, "step": 10}})
    ctx.adjuster = make_adjuster("water_marks", ctx.scenario.adjust.params)
    for i in range(5):
        ctx.queue.put(part(100.0 + i, located_at=float(i)))
    root = adjust.build(ctx)
    run_until_sample(ctx, root)
    assert bb_get("/speeds/horizontal_mm_s") == 140.0
    assert ctx.stats.timeline[0]["queue"] == 5


def test_adjuster_runs_every_period():
    ctx = make_ctx()
    root = adjust.build(ctx)
    samples = []
    for _ in range(int(2.0 / 0.02) + 2):           # 2 s at 50 Hz
        before = len(ctx.stats.timeline)
        t = ctx.clock.now()
        tick(root, ctx)
        if len(ctx.stats.timeline) > before:
            samples.append(t)
    assert len(samples) >= 3
    gaps = [b - a for a, b in zip(samples, samples[1:], strict=False)]
    assert all(0.5 - 1e-9 <= g <= 0.5 + 0.04 + 1e-9 for g in gaps), gaps
    assert bb_get("/speeds/horizontal_mm_s") == 150.0 + 5.0 * len(samples)


def test_none_leaves_speeds_unchanged():
    ctx = make_ctx(adjust={"algorithm": "none", "params": {}})
    ctx.adjuster = make_adjuster("none")
    root = adjust.build(ctx)
    tick(root, ctx, n=60)
    assert len(ctx.stats.timeline) >= 1
    assert bb_get("/speeds/horizontal_mm_s") == 150.0
    assert bb_get("/speeds/incline_pct") == 40.0
    assert bb_get("/speeds/robot_speed_pct") == 100.0
    assert ctx.stats.timeline[0]["horizontal_mm_s"] == 150.0
