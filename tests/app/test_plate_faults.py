"""A drive fault of the plate in the middle of a run, in virtual time: the
present tree resets and homes the plate and feeding goes on; a second fault within a
minute goes to the operator (FAULT) with the manual's words."""

from __future__ import annotations

from feeder_bt.config import load_scenario
from feeder_bt.control.cell import Cell, CellState
from feeder_bt.control.ticker import Ticker
from feeder_bt.core.clock import SimClock
from feeder_bt.core.errors import PlateFault
from feeder_bt.core.jobs import DoneJob
from feeder_bt.sim.plate import make_plate_sim_hal

SERVO = ("AnyFeeder plate.flip: m13: Motor 1 servo error: possibly overloaded; check for "
         "obstructions or hardware problems; error must be reset before operation can "
         "continue")


def plate_cell(seed: int = 1):
    scenario, spec = load_scenario("scenarios/plate_lenses.yaml")
    clock = SimClock()
    hal = make_plate_sim_hal(scenario, spec, clock, seed)
    cell = Cell(spec, hal, clock)
    cell.load(scenario)
    return cell, hal, Ticker(cell, fast=True)


def fail_actions(hal, at: list[int]) -> list[int]:
    """The plate's Nth actions (counted over every action) fail with a servo error."""
    plate, n, failed = hal.plate, [0], []
    for name in ("dispense", "feed", "flip", "purge"):
        real = getattr(plate, name)

        def wrapped(*a, _real=real, _name=name, **kw):
            n[0] += 1
            if n[0] in at:
                failed.append(n[0])
                return DoneJob(f"plate.{_name}", error=PlateFault(SERVO))
            return _real(*a, **kw)
        setattr(plate, name, wrapped)
    return failed


def test_a_servo_error_is_reset_and_feeding_goes_on():
    cell, hal, ticker = plate_cell()
    failed = fail_actions(hal, at=[20])
    cell.start()
    ticker.run(until=300.0)
    assert failed == [20]
    assert cell.state is CellState.RUNNING
    assert cell.stats.faults["plate"] == 1 and cell.stats.recoveries["plate"] == 1
    assert sum(cell.stats.retrieved.values()) > 100
    assert hal.world.lost() == 0


def test_two_servo_errors_in_a_minute_fault_with_the_manuals_words():
    cell, hal, ticker = plate_cell()
    fail_actions(hal, at=[20, 21])
    cell.start()
    ticker.run(until=300.0, stop=lambda: cell.state is CellState.FAULT)
    assert cell.state is CellState.FAULT
    assert "m13" in cell.fault_reason and "must be reset" in cell.fault_reason
    assert "\n" not in cell.fault_reason


def test_the_dashboard_shows_the_plate_and_its_queued_parts():
    from feeder_bt.ui.belt import BeltPanel
    cell, hal, ticker = plate_cell()
    cell.start()
    panel = BeltPanel(cell)
    plate = panel.geometry["plate"]
    assert plate == {"origin_mm": [110.0, 155.0], "size_mm": [440.0, 300.0]}
    seen = []

    def queued() -> bool:
        snap = panel.snapshot()
        seen[:] = snap["parts"]
        return bool(seen)
    ticker.run(until=120.0, stop=queued)
    assert seen
    (x0, y0), (w, h) = plate["origin_mm"], plate["size_mm"]
    for p in seen:                          # where the locator put them, on the plate
        assert x0 - 5 <= p["x_mm"] <= x0 + w + 5 and y0 - 5 <= p["y_mm"] <= y0 + h + 5


def test_a_new_golden_image_on_a_plate_purges_it_first():
    from feeder_bt.behaviours.locate import ClearForGolden
    cell, hal, ticker = plate_cell()
    cell.start()
    ticker.run(until=60.0)                    # parts on the plate by now
    cell.stop()
    ticker.run(until=90.0, stop=lambda: cell.state is CellState.STOPPED)
    assert cell.state is CellState.STOPPED and hal.world.on_horizontal
    leaf = ClearForGolden("clear", cell.ctx)
    leaf.initialise()
    assert leaf.job.name == "plate.purge"
    t = cell.clock.now()
    while not leaf.job.done and t < 120.0:
        t += 0.05
        cell.clock.advance_to(t)
        hal.step(t)
    assert leaf.job.ok and not hal.world.on_horizontal and hal.world.lost() == 0
