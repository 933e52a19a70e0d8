"""Reading a run: the report and its bounds. May import: control and every layer below.
"""
