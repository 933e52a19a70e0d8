"""Feeding policies as pure arithmetic: speed adjusters, the plate's action policy, kits and
the supply bound. May import: core, robot.
"""
