"""The simulated cell: world, devices and rendered camera images, on the clock; the HAL's
interfaces implemented over it (``devices``) and the same world in real time (``realtime``)
for the emulators. May import: core, hal (interfaces), robot, policy, vision, calibration,
config.
"""
