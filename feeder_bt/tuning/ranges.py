"""Feature ranges from samples: widened, rounded outwards, printed as YAML numbers.

Shared by ``feeder recipe suggest`` (cli/suggest.py) and ``feeder teach`` (tuning/teach.py),
so a range one of them proposes is the range the other would: the same margin and rounding.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

MARGIN_SPAN = 0.25         # widen each range by this fraction of its span ...
MARGIN_VALUE = 0.03        # ... plus this fraction of its centre
#: Shape features in the order they are preferred when several separate equally well.
PREFERRED = ("circularity", "aspect", "rectangularity", "solidity", "perimeter_mm",
             "hu1", "hu2", "holes", "hole_area_mm2")


def widen(values: list[float]) -> tuple[float, float]:
    """The samples' min/max widened by the margin (parts vary more than a few samples show)."""
    lo, hi = min(values), max(values)
    m = MARGIN_SPAN * (hi - lo) + MARGIN_VALUE * abs(hi + lo) / 2
    return round_sig(lo - m, math.floor), round_sig(hi + m, math.ceil)


def round_sig(v: float, how: Callable[[float], float]) -> float:
    """Three significant figures, rounded outwards so the range only grows."""
    if v == 0:
        return 0.0
    q = 10 ** (math.floor(math.log10(abs(v))) - 2)
    return how(v / q) * q


def fmt(v: float) -> str:
    """A number as a person would write it in YAML (no float noise)."""
    if v == int(v) and abs(v) < 1e6:
        return str(int(v))
    return f"{v:.4g}" if abs(v) >= 1e-3 else f"{v:.3e}"


def inside(f: dict[str, float], ranges: dict[str, tuple[float, float]]) -> bool:
    """Whether every ranged feature of ``f`` is within its range."""
    return all(lo <= f[n] <= hi for n, (lo, hi) in ranges.items())


def spread(samples: list[dict[str, float]], name: str) -> float:
    """Relative spread (std / |mean|) of a feature over the samples: lower is steadier."""
    v = np.array([f[name] for f in samples])
    return float(v.std() / max(abs(v.mean()), 1e-12))
