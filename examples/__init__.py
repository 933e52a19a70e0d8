"""Example leaf classes a scenario names by import path (``examples.leaves:Class``)."""
