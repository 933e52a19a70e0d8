"""The compiled kernels (``vision.kernels``), imported on first use: numba's import costs
about 0.3 s, which no command that never measures a blob should pay (``feeder --help``,
``feeder check`` of a cell). ``Locator`` calls ``warm`` when it is built (``feeder check``
of a scenario builds one to measure the drawn outlines of its classes)."""

from __future__ import annotations

import sys
import threading
from types import ModuleType

_mod: ModuleType | None = None


def kernels() -> ModuleType:
    """``feeder_bt.vision.kernels``, imported the first time it is asked for."""
    global _mod
    if _mod is None:
        from feeder_bt.vision import kernels as mod
        _mod = mod
    return _mod


# a load from the cache takes well under a second, a few seconds on a busy machine (where
# `feeder check` of a scenario, which loads them too, must print nothing more); a compile
# 13-40 s
NOTICE_AFTER_S = 5.0
NOTICE = ("feeder: compiling the locator's kernels (numba), once after installing or "
          "upgrading: 20-40 s; later runs load them from the cache")


def warm() -> None:
    """Import the kernels and compile them (or load them from numba's cache).

    Loading takes well under a second; compiling (a fresh install) 13-40 s, with nothing
    else on the screen yet: past ``NOTICE_AFTER_S`` a line on stderr says why."""
    timer = threading.Timer(NOTICE_AFTER_S, lambda: print(NOTICE, file=sys.stderr,
                                                          flush=True))
    timer.daemon = True
    timer.start()
    try:
        kernels().warm()
    finally:
        timer.cancel()
