"""Parts sliding on the horizontal belt when it speeds up or brakes harder than friction
can carry them (belt control is not free).

A part lying on the belt moves with it while the belt's acceleration ``a`` stays within
what static friction can transmit, ``|a| <= mu_s g``. Past that it slides: kinetic friction
``mu_k g`` pulls it towards the belt's speed until it matches again, and it sticks once the
belt's acceleration is back within ``mu_s g``. Each part carries its speed relative to the
belt (``SimPart.slip_v``, mm/s); sliding changes its belt-frame offset ``x0`` — the belt's
encoder does not see it, so the robot's tracking of a part that slid is off by as much.

The belt's motion is the ``Axis``'s segments of constant acceleration, so the slide has an
exact answer per segment (at most three pieces: sliding on, coming to rest relative to the
belt, sliding the other way), computed for all parts on the belt at once (``slide``).
Nothing is integrated while no part slides and the belt's acceleration stays within the
least ``mu_s g``: the common case costs a scan of the axis's last segment or two.

``BeltSlip`` is a part of ``World`` (``world.py``), kept here by concept. The model and its
figures: docs/simulator.md, "Slip under acceleration".
"""

from __future__ import annotations

import math
from collections import Counter

import numpy as np

from feeder_bt.sim.accounting import SimPart
from feeder_bt.sim.axis import Axis

G_MM_S2 = 9806.65               # standard gravity, mm/s^2


def slide(u: np.ndarray, a: float, dt: float, mus_g: np.ndarray,
          muk_g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Parts with relative speeds ``u`` (part minus belt, mm/s) on a belt accelerating at
    ``a`` (mm/s^2) for ``dt`` s: their relative speeds after, and how far each moved
    relative to the belt (mm). ``mus_g``/``muk_g``: static/kinetic friction times g, per
    part. Exact for constant ``a``: a sliding part's relative speed changes at
    ``-sign(u) muk_g - a`` until it reaches 0; it then sticks if ``|a| <= mus_g`` and
    slides the other way if not."""
    u = u.astype(float, copy=True)
    dx = np.zeros_like(u)
    rem = np.full_like(u, float(dt))
    for _ in range(3):                  # slide, stop relative to the belt, slide back
        stuck = u == 0.0
        start = stuck & (abs(a) > mus_g)
        active = (rem > 0.0) & (~stuck | start)
        if not active.any():
            break
        s = np.where(stuck, -math.copysign(1.0, a), np.sign(u))
        du = -s * muk_g - a
        with np.errstate(divide="ignore", invalid="ignore"):
            tz = np.where(u * du < 0.0, -u / du, np.inf)
        tp = np.where(active, np.minimum(rem, tz), 0.0)
        dx += u * tp + 0.5 * du * tp * tp
        u = np.where(active, u + du * tp, u)
        u[active & (tz <= rem)] = 0.0   # back at the belt's speed: exactly 0
        rem = np.where(active, rem - tp, 0.0)
    return u, dx


class BeltSlip:
    """Sliding of the parts on the horizontal belt (a part of ``World``)."""

    # what it uses of the world (``World.__init__`` makes them)
    horizontal: Axis
    on_horizontal: dict[int, SimPart]
    counts: Counter[str]

    def _start_slip(self, t: float, mu: dict[str, tuple[float, float]]) -> None:
        """Friction between the parts and the belt: (static, kinetic) per part type; a
        static zero turns slip off for that type."""
        self._slip_t = t
        self._sliding = False
        self.slid_mm = 0.0              # how far parts slid on the belt in all (mm)
        # per type: mu_s g (inf: never slides) and mu_k g (never above mu_s g)
        self._mu_g = {k: (s * G_MM_S2 if s > 0 else math.inf, min(kk, s) * G_MM_S2)
                      for k, (s, kk) in mu.items()}
        # below this acceleration no part starts to slide
        self._slip_threshold = min((m[0] for m in self._mu_g.values()), default=math.inf)

    def _slip_to(self, t: float) -> None:
        """Bring the parts' slides up to ``t`` (called before every event and at the end
        of every step, so whatever looks at a part sees it where it has slid to)."""
        t0 = self._slip_t
        if t <= t0:
            return
        self._slip_t = t
        if not self.on_horizontal:
            self._sliding = False
            return
        segs = self.horizontal.segments
        if not self._sliding and not self._hard(segs, t0, t):
            return                      # nothing slides now, and nothing starts to
        parts = list(self.on_horizontal.values())
        u = np.fromiter((p.slip_v for p in parts), float, len(parts))
        moved = np.zeros_like(u)
        mu = self._mu_g
        mus = np.fromiter((mu[p.type][0] for p in parts), float, len(parts))
        muk = np.fromiter((mu[p.type][1] for p in parts), float, len(parts))
        for seg in segs:
            lo, hi = max(seg.t0, t0), min(seg.t1, t)
            if hi <= lo:
                continue
            before = u != 0.0
            u, dx = slide(u, seg.a, hi - lo, mus, muk)
            moved += dx
            self.counts["slips"] += int(np.count_nonzero((u != 0.0) & ~before))
        start = -self.horizontal.pos(t)         # x0 of a part at the belt's start
        for p, v, dx in zip(parts, u.tolist(), moved.tolist(), strict=True):
            p.slip_v = v
            p.x0 += dx
            if p.x0 < start:                    # slid back against the ramp's foot:
                p.x0, p.slip_v = start, max(v, 0.0)     # it rides on from there
        self.slid_mm += float(np.abs(moved).sum())
        self._sliding = bool(np.any(u != 0.0))

    def _hard(self, segs: list, t0: float, t: float) -> bool:
        """Whether the belt accelerates harder than the least ``mu_s g`` in (t0, t)."""
        thr = self._slip_threshold
        for seg in reversed(segs):
            if seg.t1 <= t0:
                return False
            if seg.t0 < t and abs(seg.a) > thr:
                return True
        return False
