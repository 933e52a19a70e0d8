"""An interpreter of the V+ subset the programs in ``vplus/`` use, bound to the plant.

The V+ emulator (``feeder_bt/emulators/adept.py``) runs the shipped ``.v2`` programs with
it, as the Galil emulator runs the DMC programs: ``parse`` (lines, expressions),
``program`` (statements, control structures), ``trans`` (transformations, belts),
``task`` (execution, CALL, REACTE), ``arm`` (the robot: motions, forward processing,
tracking, reach), ``devices`` (the TCP LUNs) and ``runtime`` (memory, signals, tasks).
"""
