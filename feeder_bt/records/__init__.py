"""What a run leaves behind: the event log, the trees' history and the runs database.
May import: core and everything below behaviours (records read events the leaves raise).
"""
