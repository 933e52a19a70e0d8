"""Operator tools beyond `feeder run`, one module per sub-command (wired in cli.py)."""
