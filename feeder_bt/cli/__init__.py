"""The ``feeder`` command (``main``) and its sub-commands, one module each. The top layer:
may import every other."""
