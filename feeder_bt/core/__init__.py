"""The core: clock, jobs, errors, geometry, encoder sync, the parts queue and the scenario's
model types. Imports nothing of feeder_bt outside itself: every other layer may import it.
"""
