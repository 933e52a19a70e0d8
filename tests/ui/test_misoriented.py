"""The dashboard shows the parts placed misoriented, beside located / missed.

Browser-free: the status payload from ``CellPanel.snapshot`` on a simulated cell, and the
page's template and script that show it.
"""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell
from feeder_bt.control.operate import Limits
from feeder_bt.control.status import CellPanel
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import SimClock
from feeder_bt.sim.devices import make_sim_hal

ROOT = Path(__file__).resolve().parents[2]


def _asymmetric_links():
    """The chain-link plate without its ``symmetry: 2``: about half of the plates are
    placed turned by 180° (tests/config/test_parts_model.py). ``feeder check`` refuses
    that file (principal_axis cannot orient it), so the part is changed once loaded."""
    scenario, spec = load_scenario(ROOT / "scenarios" / "chain_links.yaml")
    assert scenario.parts["link"].symmetry == 2
    scenario.parts["link"].symmetry = 1
    return scenario, spec


def test_the_status_payload_counts_the_misoriented_parts_of_the_simulated_cell(tmp_path):
    scenario, spec = _asymmetric_links()
    clock = SimClock()
    hal = make_sim_hal(scenario, spec, clock, 1)
    cell = Cell(spec, hal, clock)
    cell.load(scenario)
    panel = CellPanel(cell, Limits.of(spec), lambda: [])
    assert panel.snapshot()[0]["misoriented"] == 0          # nothing placed yet
    cell.start()
    ticker = Ticker(cell, fast=True)
    # event-driven: tick the virtual clock until a few plates were placed turned
    ticker.run(until=clock.now() + 300.0, stop=lambda: hal.world.counts["misoriented"] >= 3)
    status = panel.snapshot()[0]
    assert status["misoriented"] == hal.world.counts["misoriented"] >= 3
    assert status["misoriented"] <= status["total_fed"]
    assert {"located", "missed", "too_far", "total_fed"} <= set(status)   # shown beside


def test_a_cell_without_a_simulated_world_shows_no_count():
    panel = SimpleNamespace(cell=SimpleNamespace(hal=SimpleNamespace(truth=None)))   # a real cell
    assert CellPanel._world_count(panel, "misoriented") is None
    assert CellPanel._world_count(panel, "scrapped") is None


def test_the_page_shows_the_count_beside_located_and_missed():
    html = (ROOT / "feeder_bt/ui/static/index.html").read_text()
    rows = re.findall(r'<td id="(st-[\w-]+)">', html)
    assert rows[rows.index("st-counts") + 1: rows.index("st-counts") + 3] == [
        "st-misoriented", "st-scrapped"]
    js = (ROOT / "feeder_bt/ui/static/app.js").read_text()
    assert re.search(r'\$\("st-misoriented"\)\.textContent = st\.misoriented == null \? "-"', js)
    assert re.search(r'\$\("st-scrapped"\)\.textContent = st\.scrapped == null \? "-"', js)
