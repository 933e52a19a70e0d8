"""The simulated cell's imperfections: what a real cell gets wrong, each from a source.

The world (``world.py``) stays the ground truth; this module says how the cell's sensors,
gripper, parts and robot depart from the ideal figures of the cell description. Every
parameter is a field of ``SimImperfections`` (``sim:`` in the cell YAML) and is listed with
its value and source in docs/simulator.md. ``sim: {ideal: true}`` turns them all off (then
every method here returns the ideal answer and draws nothing), a zero turns off one.

Honesty: the true camera mapping is given to the renderer only; the locator keeps the
cell's calibration. Random draws come from generators of their own (seeded from the run's
seed), so turning one imperfection on or off does not reshuffle the parts' flow, and the
encoder noise is a function of (seed, time sample), not of how often a counter is read.
"""

from __future__ import annotations

import math

import numpy as np

from feeder_bt.core.model import CameraCalibration, CellSpec, SimImperfections
from feeder_bt.vision.pixels import shifted

_MASK = (1 << 64) - 1


def _mix(x: int) -> int:
    """splitmix64's finaliser: a well-mixed 64-bit hash of ``x``."""
    x = (x + 0x9E3779B97F4A7C15) & _MASK
    x = ((x ^ (x >> 30)) * 0xBF58476D1CE4E5B9) & _MASK
    x = ((x ^ (x >> 27)) * 0x94D049BB133111EB) & _MASK
    return x ^ (x >> 31)


def hashed_normal(seed: int, channel: int, k: int) -> float:
    """A standard normal that depends only on (seed, channel, k): Box-Muller on two hashes."""
    h1 = _mix((seed * 1_000_003 + channel) * 0x100000001B3 + k)
    h2 = _mix(h1 ^ 0xD6E8FEB86659FD93)
    u1 = ((h1 >> 11) + 0.5) / float(1 << 53)
    u2 = (h2 >> 11) / float(1 << 53)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


def true_calibration(cell: CellSpec, residual: bool = True) -> CameraCalibration:
    """How the simulated camera really maps: ``camera.sim_truth`` (the camera as mounted)
    or the cell's calibration; a camera given as a similarity only gets the lens and tilt
    of ``sim.lens_*``/``sim.tilt_deg`` (``lensed``); then, with ``residual``, the error any
    real calibration leaves (``sim.calib_*``). ``sim: {ideal: true}``: exactly the cell's
    calibration when that is a full one (with a lens), else ``sim_truth`` or it as before.
    Only the renderer may see this."""
    cam = cell.camera
    base = cam.sim_truth or cam.calibration
    s = cell.sim
    if s.ideal:                     # no lens error: the camera is as fully calibrated
        return cam.calibration if cam.calibration.intrinsics is not None else base
    if base.intrinsics is None and base.homography is None and s.lens_focal_px > 0:
        base = lensed(base, cam.width_px, cam.height_px, s.lens_focal_px,
                      (s.lens_k1, s.lens_k2), s.tilt_deg)
    if not residual:
        return base
    return shifted(base, s.calib_offset_mm, s.calib_scale_pct, s.calib_rotation_deg)


def lensed(cal: CameraCalibration, width_px: int, height_px: int, focal_px: float,
           k: tuple[float, float], tilt_deg: tuple[float, float]) -> CameraCalibration:
    """A camera described as the similarity ``cal`` (square to the belt, no lens) given a
    lens (focal length, radial distortion ``k``, principal point at the window's centre) and
    turned ``tilt_deg`` about the image's u and v axes: its homography is the similarity
    after the turn's ``K R^T K^-1``, which leaves the window's centre pixel and the scale
    there where the similarity has them."""
    cx, cy = (width_px - 1) / 2.0, (height_px - 1) / 2.0
    kk = np.array([[focal_px, 0.0, cx], [0.0, focal_px, cy], [0.0, 0.0, 1.0]])
    a, b = (math.radians(t) for t in tilt_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    g = kk @ (rx @ ry).T @ np.linalg.inv(kk)        # tilted pixel -> square pixel
    c = np.array([cx, cy, 1.0])
    q = g @ c
    jac = (g[:2, :2] * q[2] - np.outer(q[:2], g[2, :2])) / q[2] ** 2
    fix = np.eye(3)
    fix[:2, :2] = jac
    fix[:2, 2] = q[:2] / q[2] - jac @ c[:2]
    g = np.linalg.inv(fix) @ g
    r = math.radians(cal.rotation_deg)
    sim = np.eye(3)
    sim[:2, :2] = cal.mm_per_px * np.array([[-math.sin(r), math.cos(r)],
                                            [math.cos(r), math.sin(r)]])
    sim[:2, 2] = cal.origin_mm
    h = sim @ g
    return CameraCalibration(origin_mm=cal.origin_mm, mm_per_px=cal.mm_per_px,
                             rotation_deg=cal.rotation_deg,
                             intrinsics=(focal_px, focal_px, cx, cy),
                             dist=[float(k[0]), float(k[1]), 0.0, 0.0, 0.0],
                             homography=[float(v) for v in (h / h[2, 2]).ravel()])


class Imperfections:
    """The behaviour behind ``SimImperfections`` for one world."""

    GALIL, ROBOT = 1, 2
    GALIL_KEY_S = 1e-4          # the Galil noise is drawn afresh every 0.1 ms of time

    def __init__(self, spec: SimImperfections, cpm: float, grip_d50_mm: float,
                 seed: int) -> None:
        self.spec = spec
        self.ideal = spec.ideal
        self.seed = int(seed)
        self.cpm = cpm
        # the counts the encoder truly gives per mm of belt (the cell's figure is what a
        # belt calibration measured)
        self.true_cpm = cpm if spec.ideal else cpm * (1.0 + spec.encoder_scale_pct / 100.0)
        self.d50 = grip_d50_mm
        root = np.random.SeedSequence([self.seed, 16])
        land, grip, robot = root.spawn(3)
        self.rng_land = np.random.default_rng(land)
        self.rng_grip = np.random.default_rng(grip)
        self.rng_robot = np.random.default_rng(robot)

    # ---------------------------------------------------------------- encoders
    def galil_counts(self, pos_mm: float, t: float) -> int:
        """The Galil's count for the belt at ``pos_mm`` at ``t``: the hardware latch and
        position register follow the encoder at once; quantised, with a little noise."""
        raw = pos_mm * self.true_cpm
        if not self.ideal and self.spec.encoder_noise_counts > 0:
            k = math.floor(t / self.GALIL_KEY_S)
            raw += self.spec.encoder_noise_counts * hashed_normal(self.seed, self.GALIL, k)
        return round(raw)

    def robot_sample_time(self, t: float) -> float:
        """The robot's belt channel is read once a servo period and held: the reading at
        ``t`` is the position at the start of the current period."""
        T = self.spec.robot_sample_s
        if self.ideal or T <= 0:
            return t
        return math.floor(t / T + 1e-9) * T

    def robot_counts(self, pos_mm: float, t_sample: float) -> int:
        raw = pos_mm * self.true_cpm
        if not self.ideal and self.spec.encoder_noise_counts > 0:
            T = self.spec.robot_sample_s if self.spec.robot_sample_s > 0 else self.GALIL_KEY_S
            k = round(t_sample / T)
            raw += self.spec.encoder_noise_counts * hashed_normal(self.seed, self.ROBOT, k)
        return round(raw)

    # ---------------------------------------------------------------- landing
    def landing(self, dropped: bool) -> tuple[float, float, float, float]:
        """A landing part's slide (dx, dy mm), turn (deg) and settle time (s)."""
        s = self.spec
        sigma = s.drop_slide_mm if dropped else s.land_slide_mm
        if self.ideal or (sigma <= 0 and s.land_turn_deg <= 0):
            return 0.0, 0.0, 0.0, 0.0
        dx, dy = (float(v) for v in self.rng_land.normal(0.0, max(sigma, 0.0), 2))
        turn = float(self.rng_land.normal(0.0, s.land_turn_deg)) if s.land_turn_deg > 0 else 0.0
        return dx, dy, turn, s.settle_s

    def clump_probability(self, cover: float) -> float:
        """The chance a landing part comes down against or on the one before it, with
        ``cover`` the fraction of the landing zone's belt the parts already there cover:
        ``clump_prob`` on an empty belt, rising towards 1 as the zone fills,
        p = base + (1 - base) (1 - exp(-cover / clump_cover_scale)) (docs/simulator.md)."""
        s = self.spec
        if self.ideal:
            return 0.0
        base = max(s.clump_prob, 0.0)
        if s.clump_cover_scale <= 0 or cover <= 0:
            return base
        return base + (1.0 - base) * -math.expm1(-cover / s.clump_cover_scale)

    def clump(self, cover: float = 0.0) -> tuple[float, float] | None:
        """Whether a part lands against or on the part that landed before it (its chance:
        ``clump_probability``): None, or (direction in radians, centre distance as a
        fraction of the two radii's sum)."""
        p = self.clump_probability(cover)
        if p <= 0:
            return None
        if self.rng_land.random() >= p:
            return None
        return (float(self.rng_land.uniform(-math.pi, math.pi)),
                float(self.rng_land.uniform(0.45, 0.85)))

    # ---------------------------------------------------------------- grip
    def grip_probability(self, offset_mm: float) -> float:
        """P(a suction grip holds) with the cup ``offset_mm`` from the part's centre:
        a logistic fall around the cell's ``grip_tolerance_mm`` (the ideal cell: a step)."""
        if self.ideal:
            return 1.0 if offset_mm <= self.d50 else 0.0
        w = self.spec.grip_width_mm
        if w <= 0:
            return self.spec.grip_p_centre if offset_mm <= self.d50 else 0.0
        z = (offset_mm - self.d50) / w
        return self.spec.grip_p_centre / (1.0 + math.exp(min(z, 700.0)))

    def grip_reach_mm(self) -> float:
        """Farther than this from the cup, no part is under it at all."""
        if self.ideal or self.spec.grip_width_mm <= 0:
            return self.d50
        return self.d50 + 6.0 * self.spec.grip_width_mm

    def grip_holds(self, offset_mm: float) -> bool:
        p = self.grip_probability(offset_mm)
        if p >= 1.0:
            return True
        if p <= 0.0:
            return False
        return bool(self.rng_grip.random() < p)

    # ---------------------------------------------------------------- robot
    def time_factor(self) -> float:
        """This move's time over the nominal one (the nominal ``RobotModel`` stays what
        policies price picks with)."""
        cv = self.spec.robot_time_cv
        if self.ideal or cv <= 0:
            return 1.0
        return float(np.clip(1.0 + cv * self.rng_robot.standard_normal(), 0.8, 1.25))
