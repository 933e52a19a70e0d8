"""The AnyFeeder-class plate feeder on its serial line (issue 31, docs/plate-feeders.md)."""
