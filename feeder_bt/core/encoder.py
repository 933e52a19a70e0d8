"""Conveyor encoder synchronisation (thesis 2.3.1 and 5.3.1).

The conveyor controller (Galil) counts the belt encoder in a 32-bit signed counter and the
robot controller (Adept) counts the same pulses in a 24-bit signed counter; each wraps at
its own width, the robot's every few minutes. A latched conveyor count is useless to the
robot until it is translated into the robot's counter, so ``EncoderSync`` carries the two
counts forward together, applying each conveyor difference modulo the robot's width.

Pure arithmetic: no hardware, no clock. The caller owns the locking if it shares one.
"""

from __future__ import annotations


def wrap(value: int, bits: int) -> int:
    """Fold any integer into a ``bits``-wide two's-complement counter, as the hardware does."""
    if bits < 1:
        raise ValueError(f"bits must be >= 1, got {bits}")
    half = 1 << (bits - 1)
    return ((value + half) % (1 << bits)) - half


def diff(a: int, b: int, bits: int) -> int:
    """Signed shortest ``a - b`` on a wrapping counter.

    Right whenever the true movement between the readings is under half a wrap, which
    is why the sync must be consulted at least that often.
    """
    return wrap(a - b, bits)


class EncoderSync:
    """Translates conveyor counts (e.g. a latched one) into robot counts across roll-over.

    ``reset`` records one simultaneous pair of counts while the belt is stationary (the
    thesis's constructor refused to start on a moving belt). Every newer conveyor count
    seen by ``to_robot`` advances the reference, so calling it at least once per half-wrap
    of the larger counter keeps the two in step indefinitely; older counts (a latch from
    a frame taken earlier) are translated without moving the reference back.

    With the default widths the limit never bites (2**24 divides 2**32, so a conveyor
    difference misread by a whole conveyor wrap is still right modulo the robot's), but
    the reference is kept anyway so other widths, e.g. a narrower conveyor counter, work.
    """

    def __init__(self, conveyor_bits: int = 32, robot_bits: int = 24) -> None:
        if conveyor_bits < 2 or robot_bits < 2:
            raise ValueError("counter widths must be at least 2 bits")
        self.conveyor_bits = conveyor_bits
        self.robot_bits = robot_bits
        self._conveyor_ref: int | None = None
        self._robot_ref = 0

    @property
    def is_reset(self) -> bool:
        """False until ``reset``: before that no translation can be right."""
        return self._conveyor_ref is not None

    @property
    def reference(self) -> tuple[int, int] | None:
        """The current (conveyor, robot) pair the translation is anchored to."""
        if self._conveyor_ref is None:
            return None
        return self._conveyor_ref, self._robot_ref

    def reset(self, conveyor_count: int, robot_count: int) -> None:
        """Anchor the two counters to each other; the belt must not be moving."""
        self._conveyor_ref = wrap(conveyor_count, self.conveyor_bits)
        self._robot_ref = wrap(robot_count, self.robot_bits)

    def to_robot(self, conveyor_count: int) -> int:
        """Robot count at the moment the conveyor counter read ``conveyor_count``."""
        if self._conveyor_ref is None:
            raise RuntimeError("EncoderSync.reset must be called (belt stopped) before use")
        count = wrap(conveyor_count, self.conveyor_bits)
        moved = diff(count, self._conveyor_ref, self.conveyor_bits)
        robot = wrap(self._robot_ref + moved, self.robot_bits)
        if moved > 0:
            self._conveyor_ref, self._robot_ref = count, robot
        return robot

    def robot_diff(self, a: int, b: int) -> int:
        """Counts the belt moved from robot count ``b`` to ``a``, across a robot wrap."""
        return diff(a, b, self.robot_bits)

    def mm_between(self, a_robot: int, b_robot: int, counts_per_mm: float) -> float:
        """Belt travel in mm from ``b_robot`` to ``a_robot`` (negative if backwards)."""
        if counts_per_mm == 0:
            raise ValueError("counts_per_mm must be non-zero")
        return self.robot_diff(a_robot, b_robot) / counts_per_mm


class FreshAnchor:
    """The pair of counts a sync is anchored on: fresh, aged, and at rest.

    Both controllers' counts reach the PC as cached reads of different ages: the Galil's
    from a ``TP`` poll, the robot's from its position poller. A pair taken from the caches
    as they stand may hold a count read before the belt stopped, or one read long ago
    over a link that has since dropped, and the sync is then off by however far the belt
    moved in between, for the whole run. ``offer`` is fed the caches' counts with their
    ages (seconds since each was read, ``now`` on the same clock) each poll; a pair is
    returned only when each counter has been read twice, after the anchor began and
    within ``max_age_s`` of ``now``, with the same count both times (the belt is at rest),
    the conveyor's count carried to the moment of the robot's read by the speed its two
    reads show (zero at rest: the age compensation DriftWatch applies while running).
    Commissioning (``feeder commission adept``) and every run's set-up
    (``behaviours.setup.SyncEncoders``) anchor through this one helper.
    """

    def __init__(self, conveyor_bits: int = 32, robot_bits: int = 24, max_age_s: float = 0.5,
                 rest_counts: int = 0) -> None:
        self.conveyor_bits, self.robot_bits = conveyor_bits, robot_bits
        self.max_age_s, self.rest_counts = max_age_s, rest_counts
        self._conv: list[tuple[float, int]] = []       # (time of read, count), distinct reads
        self._robot: list[tuple[float, int]] = []
        self.why = "no fresh reads yet"                 # why no pair yet (for a time-out)

    def offer(self, now: float, conveyor: int, conveyor_age: float | None, robot: int,
              robot_age: float | None) -> tuple[int, int] | None:
        """One look at both caches; the anchoring ``(conveyor, robot)`` pair, or None."""
        for reads, count, age, what in ((self._conv, conveyor, conveyor_age, "conveyor"),
                                        (self._robot, robot, robot_age, "robot")):
            if age is None or age > self.max_age_s:
                self.why = f"the {what} count is not fresh (age {age})"
                return None
            t = now - age
            if not reads or t > reads[-1][0] + 1e-9:
                reads.append((t, count))
                del reads[:-2]
        if len(self._conv) < 2 or len(self._robot) < 2:
            self.why = "waiting for a second fresh read of each counter"
            return None
        (tc0, c0), (tc1, c1) = self._conv
        (_, r0), (tr1, r1) = self._robot
        if (abs(diff(c1, c0, self.conveyor_bits)) > self.rest_counts
                or abs(diff(r1, r0, self.robot_bits)) > self.rest_counts):
            self.why = "the belt is moving (the counts change between reads)"
            return None
        speed = diff(c1, c0, self.conveyor_bits) / (tc1 - tc0) if tc1 > tc0 else 0.0
        return wrap(c1 + round(speed * (tr1 - tc1)), self.conveyor_bits), r1


class DriftWatch:
    """Re-checks, during a run, that the two controllers still count the same belt.

    The sync is anchored once, at rest (``EncoderSync.reset``); a counter that drops or gains
    pulses afterwards (noise on a long encoder cable, a loose shield) moves every pick by
    the difference, and nothing else notices until grips miss. Each ``sample`` compares the
    robot's count with the conveyor's translated through the sync. The two counts are
    cached reads taken at different moments (``ages``), so the conveyor's count is carried
    forward by the belt's measured speed to the moment of the robot's read; a read older
    than ``max_age_s`` (a link down, a stalled poller) gives no sample. The robot controller
    samples its belt channel once a ``robot_sample_s`` and holds it, so its count shows the
    belt half a period earlier on average; the prediction allows for that. The verdict is the
    median of the last ``window`` samples: one read caught mid-acceleration moves nothing.
    """

    def __init__(self, sync: EncoderSync, counts_per_mm: float, window: int = 9,
                 max_age_s: float = 0.25, robot_sample_s: float = 0.0) -> None:
        if window < 1:
            raise ValueError("window must be at least 1")
        self.sync, self.counts_per_mm = sync, counts_per_mm
        self.window, self.max_age_s = window, max_age_s
        # the robot's count is a sample held for a period: on average it shows the belt
        # half a period before the read
        self.sample_delay_s = robot_sample_s / 2.0
        self.samples: list[float] = []
        self._prev: tuple[float, int] | None = None      # (time of read, conveyor count)
        self.max_abs_mm = 0.0
        self.taken = 0
        self.max_doubt_mm = 0.5           # a pair timed worse than this gives no sample
        self.doubtful = 0                 # pairs left out for it
        self._over = 0                    # verdicts in a row past the limit

    def sample(self, now: float, conveyor: int, conveyor_age: float | None, robot: int,
               robot_age: float | None, doubt_s: float = 0.0) -> float | None:
        """Feed one pair of cached reads; the filtered drift in mm (robot ahead of the
        conveyor is positive) once the window is full, else None. ``doubt_s``: how far
        either read's moment of sampling may be from its stamp (half of each round trip);
        a pair whose doubt moves a running belt more than ``max_doubt_mm`` gives no
        sample: a host slow to hear its replies is not an encoder that lost pulses."""
        if (not self.sync.is_reset or conveyor_age is None or robot_age is None
                or conveyor_age > self.max_age_s or robot_age > self.max_age_s):
            return None
        t_conv, t_robot = now - conveyor_age, now - robot_age - self.sample_delay_s
        prev, self._prev = self._prev, (t_conv, conveyor)
        if prev is None or t_conv - prev[0] <= 1e-6:
            return None                                  # no speed yet to carry it forward
        speed = diff(conveyor, prev[1], self.sync.conveyor_bits) / (t_conv - prev[0])
        if abs(speed) * doubt_s > self.max_doubt_mm * self.counts_per_mm:
            self.doubtful += 1
            return None
        predicted = self.sync.to_robot(conveyor) + round(speed * (t_robot - t_conv))
        self.samples.append(self.sync.robot_diff(robot, predicted) / self.counts_per_mm)
        self.taken += 1
        del self.samples[:-self.window]
        if len(self.samples) < self.window:
            return None
        drift = sorted(self.samples)[len(self.samples) // 2]
        self.max_abs_mm = max(self.max_abs_mm, abs(drift))
        return drift

    def held_past(self, drift: float, limit_mm: float) -> bool:
        """Whether the verdict ``drift`` (from ``sample``) calls for a fault: past twice
        ``limit_mm``, or past it for a whole window of verdicts in a row. Lost pulses are a
        step that stays; a host late to hear its replies (a loaded machine, a slow hop on
        the link) gives bursts of late stamps that come and go, and a burst can carry a
        median just past the limit, but not for a window of verdicts, nor twice as far."""
        self._over = self._over + 1 if abs(drift) > limit_mm else 0
        return self._over >= self.window or abs(drift) > 2 * limit_mm
