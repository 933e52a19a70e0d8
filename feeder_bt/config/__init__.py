"""Scenarios (part-specific knowledge) and cell descriptions (hardware), loaded from YAML:
the loaders, JSON Schemas, checks, overlays, plug-ins, fault and supply plans. May import:
core, hal, robot, policy, vision, calibration."""

from feeder_bt.config.files import check_files
from feeder_bt.config.loader import load_cell, load_scenario
from feeder_bt.core.model import CellSpec, Scenario

__all__ = ["CellSpec", "Scenario", "check_files", "load_cell", "load_scenario"]
