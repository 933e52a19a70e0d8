"""The compiled kernels (``vision.kernels``), imported on first use: numba's import costs
about 0.3 s, which no command that never locates a part should pay (``feeder --help``,
``feeder check``). ``Locator`` calls ``warm`` when it is built."""

from __future__ import annotations

from types import ModuleType

_mod: ModuleType | None = None


def kernels() -> ModuleType:
    """``feeder_bt.vision.kernels``, imported the first time it is asked for."""
    global _mod
    if _mod is None:
        from . import kernels as mod
        _mod = mod
    return _mod


def warm() -> None:
    """Import the kernels and compile them (or load them from numba's cache)."""
    kernels().warm()
