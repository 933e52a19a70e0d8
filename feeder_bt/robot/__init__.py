"""The arm: pick-and-place time models, the online fit, the SCARA's kinematics, the gripper.
May import: core.
"""
