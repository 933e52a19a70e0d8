"""Scenarios (part-specific knowledge) and cell descriptions (hardware), loaded from YAML."""

from feeder_bt.scenario.loader import check_files, load_cell, load_scenario
from feeder_bt.scenario.model import CellSpec, Scenario

__all__ = ["CellSpec", "Scenario", "check_files", "load_cell", "load_scenario"]
