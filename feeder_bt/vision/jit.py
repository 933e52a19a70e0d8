"""The compiled kernels (``vision.kernels``), imported on first use: numba's import costs
about 0.3 s, which no command that never locates a part should pay (``feeder --help``,
``feeder check``). ``Locator`` calls ``warm`` when it is built."""

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


NOTICE = ("feeder: compiling the locator's kernels (numba), once after installing or "
          "upgrading: 20-40 s; later runs load them from the cache")


def warm() -> None:
    """Import the kernels and compile them (or load them from numba's cache).

    Loading takes about a second; compiling (a fresh install) 13-40 s, with nothing else on
    the screen yet: a line on stderr says why as soon as numba starts compiling, and only
    then (numba's ``numba:compile`` event fires for a compile, never for a cache load, so a
    slow load on a busy machine says nothing)."""
    from numba.core import event

    said = threading.Event()

    class _Notice(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            if not said.is_set():
                said.set()
                print(NOTICE, file=sys.stderr, flush=True)

        def on_end(self, ev: event.Event) -> None:
            pass

    with event.install_listener("numba:compile", _Notice()):
        kernels().warm()
