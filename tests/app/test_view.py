"""The terminal view fits the terminal: a minute of lenses in virtual time, drawn at every
tick into 80 x 24 (and smaller), keeps its header and status line on screen; the trees fold
to their running branches; the waiting line says why nothing is picked yet."""

from __future__ import annotations

import io
import re

import pytest

from feeder_bt.app.factory import make_hal
from feeder_bt.app.view import LiveView, status_line, tree_lines
from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import SimClock
from feeder_bt.sim.devices import make_sim_hal


def _cell(path: str = "scenarios/lenses.yaml", seed: int = 1) -> tuple[Cell, Ticker]:
    scenario, spec = load_scenario(path)
    clock = SimClock()
    cell = Cell(spec, make_sim_hal(scenario, spec, clock, seed), clock)
    cell.load(scenario)
    return cell, Ticker(cell, fast=True)


@pytest.mark.parametrize("width,height", [(80, 24), (60, 16), (40, 12)])
def test_a_minute_of_lenses_fits_the_terminal(width, height):
    cell, ticker = _cell()
    view = LiveView(cell, out=io.StringIO())
    rows = height - 1                      # the row under the view holds the cursor
    seen: dict[str, float] = {}
    folded = 0

    def check() -> None:
        nonlocal folded
        lines = view.lines(width, rows)
        assert len(lines) <= rows
        assert all(len(s) <= width for s in lines), [s for s in lines if len(s) > width]
        assert lines[0].startswith(f"feeder_bt · lenses on {cell.cell.name}")
        i = 1 if width >= 80 else 2        # narrower: "Ctrl-C stops ..." on a line of its own
        assert lines[i].startswith(cell.state.value), lines[i]
        assert "parts/min" in " ".join(lines[i:i + 2])        # 40 columns: on two lines
        assert any(s.startswith("located ") for s in lines[i + 1:i + 4])
        folded += any("(+" in s for s in lines)
        m = re.search(r"waiting for the first parts to reach the (camera|robot)",
                      " ".join(lines[i + 2:i + 7]))      # wrapped when narrow
        if m:
            seen.setdefault(m.group(0), cell.clock.now())
        if cell.stats.total_retrieved:
            assert not any(s.startswith("waiting for") for s in lines)

    cell.start()
    ticker.run(until=60.0, every=check)
    assert cell.state is CellState.RUNNING and cell.stats.total_retrieved > 10
    # first the camera, then the robot: what a newcomer needs to know in the first 20 s
    camera = seen["waiting for the first parts to reach the camera"]
    robot = seen["waiting for the first parts to reach the robot"]
    assert camera < robot < 60.0
    assert folded > 0                      # 100-odd nodes never fit: they were folded
    cell.hal.close()


def test_trees_fold_to_the_running_branches():
    cell, ticker = _cell()
    cell.start()
    ticker.run(until=40.0)
    root = cell.root
    whole = tree_lines(root, 1000)
    assert len(whole) == sum(1 for _ in root.iterate())
    folded = tree_lines(root, 40)
    assert len(folded) <= 40 < len(whole)
    running = [n for n in root.iterate() if n.status.name == "RUNNING"]
    names = "\n".join(folded)
    for n in running:                      # every running node is still there
        assert f"{n.name} [*]" in names, n.name
    tight = tree_lines(root, 8)
    assert len(tight) == 8 and tight[-1].startswith("… ") and "more lines" in tight[-1]
    assert tree_lines(root, 0) == []
    cell.hal.close()


def test_on_a_pipe_one_status_line_every_ten_seconds():
    cell, ticker = _cell()
    out = io.StringIO()
    view = LiveView(cell, out=out, feed_seconds=lambda: cell.clock.now())
    assert not view.tty
    cell.start()
    ticker.run(until=45.0, every=view.update)
    view.update(force=True)                # the last line, as a run's end draws it
    lines = out.getvalue().splitlines()
    assert 5 <= len(lines) <= 7
    assert lines[-1] == status_line(cell, cell.clock.now())
    assert all(s.split()[0] in ("STARTING", "RUNNING") for s in lines)
    cell.hal.close()


def test_the_ascii_view_is_ascii():
    cell, ticker = _cell()
    view = LiveView(cell, fmt="ascii", out=io.StringIO())
    cell.start()
    ticker.run(until=30.0)
    text = "\n".join(view.lines(80, 23))
    assert text.isascii() and "[*]" in text and "- Ctrl-C stops" in text
    cell.hal.close()


def test_a_plate_cell_shows_the_plate_s_actions_not_belt_speeds():
    """A plate cell has no belts: its status line says what the plate did instead."""
    scenario, spec = load_scenario("scenarios/plate_lenses.yaml")
    hal, clock = make_hal("sim", scenario, spec, seed=1)
    cell = Cell(spec, hal, clock)
    cell.load(scenario)
    ticker = Ticker(cell, fast=True)
    cell.start()
    ticker.run(until=120.0)
    line = status_line(cell)
    counts = cell.stats.counts
    assert counts["plate_dispense"] > 0 and f"dispense {counts['plate_dispense']}" in line
    assert "plate " in line and "belt " not in line and "incline" not in line
    assert "too far" not in line
    cell.hal.close()
