"""Kinematics of one simulated conveyor axis.

The motion is a list of segments of constant acceleration, so that position, speed and
"when does the belt reach position p" have exact answers. Events in the simulated world
then happen at the same virtual times however coarsely the world is stepped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass
class Segment:
    t0: float
    p0: float
    v0: float
    a: float
    t1: float = math.inf   # end of the segment

    def pos(self, t: float) -> float:
        dt = t - self.t0
        return self.p0 + self.v0 * dt + 0.5 * self.a * dt * dt

    def vel(self, t: float) -> float:
        return self.v0 + self.a * (t - self.t0)


class Axis:
    """Position in mm of a belt (cumulative), driven by jog and relative-move commands.

    A command above ``max_speed`` runs at ``max_speed`` — a motor saturates — and is
    counted in ``clamped`` (never silent: the simulated HAL refuses such a command before
    it gets here, so in a simulated run the count stays 0; the Galil emulator's raw
    commands can still saturate the motor)."""

    def __init__(self, accel_mm_s2: float, max_mm_s: float) -> None:
        self.accel = accel_mm_s2
        self.max_speed = max_mm_s
        self.clamped = 0
        self.segments: list[Segment] = [Segment(0.0, 0.0, 0.0, 0.0)]
        self.commanded = 0.0
        self.version = 0          # bumps on every new command: pending notifications re-hint

    # ---------------------------------------------------------------- queries
    def _seg(self, t: float) -> Segment:
        for seg in reversed(self.segments):
            if seg.t0 <= t:
                return seg
        return self.segments[0]

    def pos(self, t: float) -> float:
        return self._seg(t).pos(t)

    def vel(self, t: float) -> float:
        return self._seg(t).vel(t)

    def settle_time(self) -> float:
        """When the last command's motion profile reaches its final speed."""
        last = self.segments[-1]
        return last.t0 if last.a == 0.0 else last.t1

    def time_at(self, p: float, after: float) -> float | None:
        """First time >= ``after`` at which the position reaches ``p`` (moving forward).

        The world asks this several times a tick: ``Segment.pos`` is written out here (the
        same expression) and the segments are indexed rather than sliced.
        """
        segs = self.segments
        n = len(segs)
        start = n - 1
        while start > 0 and segs[start].t0 > after:
            start -= 1
        reach = p - 1e-9
        for i in range(start, n):
            seg = segs[i]
            if seg.t1 <= after:
                continue
            lo = max(seg.t0, after)
            dt = lo - seg.t0
            if seg.p0 + seg.v0 * dt + 0.5 * seg.a * dt * dt >= reach:
                return lo
            t = _first_reach(seg, p, lo)
            if t is not None and t <= seg.t1:
                return t
        return None

    # ---------------------------------------------------------------- commands
    def above_limit(self, speed: float) -> bool:
        """``speed`` (mm/s, signed) is beyond what this axis can run."""
        return abs(speed) > self.max_speed * (1.0 + 1e-9)

    def _limit(self, speed: float) -> float:
        if self.above_limit(speed):
            self.clamped += 1
            return math.copysign(self.max_speed, speed)
        return speed

    def _cut(self, t: float) -> tuple[float, float]:
        """Drop the planned future from ``t``; return position and speed there."""
        seg = self._seg(t)
        p, v = seg.pos(t), seg.vel(t)
        self.segments = [s for s in self.segments if s.t0 < t]
        if self.segments:
            self.segments[-1].t1 = t
        if len(self.segments) > 64:               # forget the distant past
            self.segments = self.segments[-32:]
        self.version += 1
        return p, v

    def jog(self, t: float, speed: float) -> float:
        """Ramp to ``speed`` (mm/s, signed); returns when the speed is reached."""
        speed = self._limit(speed)
        p, v = self._cut(t)
        self.commanded = speed
        if abs(speed - v) < 1e-9:
            self.segments.append(Segment(t, p, speed, 0.0))
            return t
        a = self.accel if speed > v else -self.accel
        t_ramp = t + (speed - v) / a
        self.segments.append(Segment(t, p, v, a, t_ramp))
        self.segments.append(Segment(t_ramp, self.segments[-1].pos(t_ramp), speed, 0.0))
        return t_ramp

    def move(self, t: float, distance: float, speed: float) -> float:
        """Relative trapezoidal move from rest (or from the current speed); returns its end."""
        p, v = self._cut(t)
        speed = self._limit(abs(speed))
        sign = 1.0 if distance >= 0 else -1.0
        d = abs(distance)
        v = v * sign
        a = self.accel
        # decelerate/accelerate to cruise, cruise, decelerate to 0 (v assumed >= 0 along d)
        v = max(0.0, v)
        d_up = (speed * speed - v * v) / (2 * a)
        d_down = speed * speed / (2 * a)
        if d_up + d_down > d:       # triangular profile
            vp = math.sqrt(max(v * v, (2 * a * d + v * v) / 2))
            d_up = (vp * vp - v * v) / (2 * a)
            d_down = vp * vp / (2 * a)
            speed = vp
        t1 = t + (speed - v) / a
        t2 = t1 + (d - d_up - d_down) / speed if speed > 0 else t1
        t3 = t2 + speed / a
        s = sign
        self.segments.append(Segment(t, p, s * v, s * a, t1))
        p1 = self.segments[-1].pos(t1)
        self.segments.append(Segment(t1, p1, s * speed, 0.0, t2))
        p2 = self.segments[-1].pos(t2)
        self.segments.append(Segment(t2, p2, s * speed, -s * a, t3))
        self.segments.append(Segment(t3, p + distance, 0.0, 0.0))
        self.commanded = 0.0
        return t3


def _first_reach(seg: Segment, p: float, lo: float) -> float | None:
    """Earliest t >= lo with seg.pos(t) = p, on an upward crossing."""
    # p0 + v0 dt + a/2 dt^2 = p, dt measured from seg.t0
    a, b, c = 0.5 * seg.a, seg.v0, seg.p0 - p
    if abs(a) < 1e-12:          # the usual case (a belt at speed): one root, no list
        if abs(b) <= 1e-12:
            return None
        t = seg.t0 + -c / b
        if t >= lo - 1e-12 and seg.v0 + seg.a * (t - seg.t0) >= -1e-9:
            return t
        return None
    roots: list[float] = []
    disc = b * b - 4 * a * c
    if disc >= 0:
        r = math.sqrt(disc)
        roots.extend(((-b - r) / (2 * a), (-b + r) / (2 * a)))
    best = None
    for dt in roots:
        t = seg.t0 + dt
        if t >= lo - 1e-12 and seg.vel(t) >= -1e-9 and (best is None or t < best):
            best = t
    return best
