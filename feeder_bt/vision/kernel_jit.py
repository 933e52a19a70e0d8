"""The decorator every kernel module compiles with (numba, cached beside the source), apart
from ``jit``, which imports the kernels lazily: so no kernel module imports its importer."""

from __future__ import annotations


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
