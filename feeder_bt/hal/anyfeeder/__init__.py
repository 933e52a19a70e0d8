"""The AnyFeeder-class plate feeder on its serial line (docs/plate-feeders.md)."""
