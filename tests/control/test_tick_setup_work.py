"""The pixel table of a distorted camera (``PixelGrid``, 12 ms for a 640 x 484 frame) is
made when the cell builds its locator, never on a tick: built when the golden image was
set, it made that one tick 12 ms long, past a 200 Hz tick's 5 ms budget."""

from __future__ import annotations

from pathlib import Path

import feeder_bt.control.ticker as ticker
import feeder_bt.vision.locator as locator
from feeder_bt.app.run import RunOptions, run_job

ROOT = Path(__file__).resolve().parents[2]


def test_no_pixel_table_is_built_on_a_tick(monkeypatch):
    ticking = [False]
    built: list[bool] = []          # for each table built: was the cell ticking?
    real_grid, real_tick = locator.PixelGrid, ticker.Ticker.tick_once

    def grid(*args, **kwargs):
        built.append(ticking[0])
        return real_grid(*args, **kwargs)

    def tick_once(self):
        ticking[0] = True
        try:
            real_tick(self)
        finally:
            ticking[0] = False

    monkeypatch.setattr(locator, "PixelGrid", grid)
    monkeypatch.setattr(ticker.Ticker, "tick_once", tick_once)
    report = run_job(RunOptions(scenario=str(ROOT / "scenarios/lenses.yaml"), duration=60.0,
                                fast=True, seed=1, view="none", db=None))
    assert report["parts"]["located"] > 0           # the golden image set, frames seen
    assert built == [False]                         # one table, made before the ticks
