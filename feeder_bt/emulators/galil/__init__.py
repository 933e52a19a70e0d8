"""The Galil DMC controller emulator: its link, axes, commands and DMC interpreter.
"""
