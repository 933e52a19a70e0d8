"""Putting a cell together: ``run_job``, the HAL factory, the terminal view and tree drawing.
May import: ui, plant, analysis and every layer below.
"""
