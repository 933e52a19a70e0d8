"""feeder_bt: a behaviour-tree cell controller for vision-based flexible parts feeders."""

__version__ = "0.1.0"
