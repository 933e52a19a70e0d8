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


def _jit(fn=None, **kw):
    """numba's ``njit(cache=True, nogil=True)`` for the kernels' modules (which only
    ``kernels`` imports); where numba finds no writable cache directory, compiled in memory
    in each process instead."""
    if fn is None:
        return lambda f: _jit(f, **kw)
    from numba import njit
    try:
        return njit(cache=True, nogil=True, **kw)(fn)
    except RuntimeError:            # numba found no writable cache directory
        return njit(nogil=True, **kw)(fn)


def warm() -> None:
    """Import the kernels and compile them (or load them from numba's cache)."""
    kernels().warm()
