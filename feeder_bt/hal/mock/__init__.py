"""A scripted HAL for tick-level tests: every call is recorded, every job waits for the
test to finish it (``succeed``/``fail``), so a test decides exactly when things happen."""

from feeder_bt.hal.mock.hal import MockHal, MockJob

__all__ = ["MockHal", "MockJob"]
