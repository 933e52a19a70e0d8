"""The four feeding trees and the set-up / clean-up sequences, built from a scenario."""

from feeder_bt.trees.build import build_cleanup, build_feeding, build_setup

__all__ = ["build_feeding", "build_setup", "build_cleanup"]
