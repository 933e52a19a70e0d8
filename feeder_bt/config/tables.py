"""The tables of allowed values a scenario, cell or fault plan is checked against.

Enumerations, numeric ranges and adjuster parameters are module constants so that other
modules (the loader, the JSON Schemas, the CLI, docs, adjusters) reuse the same tables.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from feeder_bt.config.faults import (
    COMMS_DEVICES,
    FAULT_KINDS,
    LINK_DEATHS,
    PHASES,
    FaultRate,
    ScriptedFault,
)
from feeder_bt.core.model import (
    AdeptSpec,
    AdjustParams,
    CameraCalibration,
    CameraSpec,
    CellSpec,
    ConveyorSpec,
    EncoderSpec,
    GalilSpec,
    HopperSpec,
    IoSignal,
    LocateParams,
    Morphology,
    OutlineMatch,
    PartSpec,
    PickSpec,
    PresentParams,
    PylonSpec,
    RenderSpec,
    RetrieveParams,
    RobotSpec,
    Ruler,
    Scenario,
    SimImperfections,
    StablePose,
    TargetSpec,
    Threshold,
    VisionClass,
    VisionRecipe,
)
from feeder_bt.core.plate_model import (
    PlatePolicy,
    PlateRepetitions,
    PlateSpec,
    PlateSpeeds,
)

# ============================================================================ allowed values

PRESENT_MODES: tuple[str, ...] = ("continuous", "incremental")
RETRIEVE_POLICIES: tuple[str, ...] = ("fifo", "earliest_deadline", "shortest_cycle",
                                      "lookahead")
THRESHOLD_METHODS: tuple[str, ...] = ("fixed", "otsu", "adaptive")
FOREGROUNDS: tuple[str, ...] = ("dark", "light")
LIGHTINGS: tuple[str, ...] = ("backlit", "frontlit")
TARGET_KINDS: tuple[str, ...] = ("chessboard", "circles", "acircles", "charuco")
ORIENTATION_METHODS: tuple[str, ...] = ("none", "principal_axis", "cut_corner", "outline",
                                        "moment")
CELL_HALS: tuple[str, ...] = ("sim", "emulated", "real")
IO_DIRS: tuple[str, ...] = ("in", "out")
#: pylon cameras (feeder_bt.hal.camera.pylon): the FrameStart trigger's source, and the
#: mono formats a frame is converted from (GenICam SFNC names)
PYLON_TRIGGERS: tuple[str, ...] = ("Software", "Line1", "Line2", "Line3")
PYLON_PIXEL_FORMATS: tuple[str, ...] = ("Mono8", "Mono10", "Mono12", "Mono16")
#: the FrameStart edges that give one frame per pulse (AnyEdge would give two, the Level
#: modes a frame for as long as the line is held)
PYLON_TRIGGER_ACTIVATIONS: tuple[str, ...] = ("RisingEdge", "FallingEdge")

#: Shape kinds and the ``Shape`` fields each one is written with (all required).
SHAPE_KINDS: dict[str, tuple[str, ...]] = {
    "disc": ("diameter_mm",),
    "rect": ("size_mm",),
    "polygon": ("points_mm",),
}
#: Optional ``Shape`` fields of each kind (holes).
SHAPE_OPTIONAL: dict[str, tuple[str, ...]] = {"disc": ("hole_mm",), "polygon": ("holes_mm",)}

#: Conveyors a cell describes; ``return`` is not a belt, only its transit time.
CONVEYOR_NAMES: tuple[str, ...] = ("horizontal", "incline")

#: Tolerance on the sum of a part's pose probabilities.
PROBABILITY_TOLERANCE = 1e-6


@dataclass(frozen=True)
class Range:
    """A numeric interval; ``None`` bounds are open-ended, ``*_open`` excludes the bound."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def contains(self, v: float) -> bool:
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return not (self.hi is not None and (v >= self.hi if self.hi_open else v > self.hi))

    def describe(self) -> str:
        if self.lo is not None and self.hi is not None:
            return (f"in {'(' if self.lo_open else '['}{_num(self.lo)}, "
                    f"{_num(self.hi)}{')' if self.hi_open else ']'}")
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {_num(self.lo)}"
        if self.hi is not None:
            return f"{'<' if self.hi_open else '<='} {_num(self.hi)}"
        return "any number"


POSITIVE = Range(lo=0, lo_open=True)
NON_NEGATIVE = Range(lo=0)
GREY = Range(0, 255)

#: Enumerated string fields: (dataclass, field) -> allowed values.
ENUMS: dict[tuple[type, str], tuple[str, ...]] = {
    (PresentParams, "mode"): PRESENT_MODES,
    (RetrieveParams, "policy"): RETRIEVE_POLICIES,
    (Threshold, "method"): THRESHOLD_METHODS,
    (VisionRecipe, "orientation"): ORIENTATION_METHODS,
    (VisionClass, "orientation"): ORIENTATION_METHODS,
    (VisionRecipe, "foreground"): FOREGROUNDS,
    (RenderSpec, "lighting"): LIGHTINGS,
    (TargetSpec, "kind"): TARGET_KINDS,
    (CellSpec, "hal"): CELL_HALS,
    (IoSignal, "dir"): IO_DIRS,
    (GalilSpec, "servo_on"): ("never", "start", "reconnect"),
    (GalilSpec, "limit_switches"): ("low", "high"),
    (GalilSpec, "latch_edge"): ("falling", "rising"),
    (IoSignal, "active"): ("high", "low"),
    (GalilSpec, "free_handles"): ("ours", "others", "none"),
    (PylonSpec, "trigger"): PYLON_TRIGGERS,
    (PylonSpec, "pixel_format"): PYLON_PIXEL_FORMATS,
    (PylonSpec, "trigger_activation"): PYLON_TRIGGER_ACTIVATIONS,
}

#: Numeric fields: (dataclass, field) -> allowed interval. Cross-file limits (conveyor
#: max speeds, camera window) are checked separately in ``load_scenario``.
RANGES: dict[tuple[type, str], Range] = {
    (Scenario, "tick_hz"): Range(5, 1000),
    (StablePose, "probability"): Range(0, 1),
    (PartSpec, "orientation_tolerance_deg"): Range(0, 180, lo_open=True),
    (PartSpec, "symmetry"): Range(1, 360),
    (PartSpec, "max_passes"): Range(0, 10_000),
    (PartSpec, "belt_mu_static"): Range(0, 2),
    (PartSpec, "belt_mu_kinetic"): Range(0, 2),
    (PickSpec, "cup_radius_mm"): NON_NEGATIVE,
    (PickSpec, "clearance_mm"): NON_NEGATIVE,
    (Threshold, "value"): GREY,
    (Threshold, "block_px"): Range(lo=3),
    (Morphology, "open_px"): NON_NEGATIVE,
    (Morphology, "close_px"): NON_NEGATIVE,
    (VisionRecipe, "min_area_mm2"): NON_NEGATIVE,
    (VisionRecipe, "min_hole_mm2"): NON_NEGATIVE,
    (OutlineMatch, "min_iou"): Range(0, 1, lo_open=True),
    (OutlineMatch, "margin"): Range(0, 1),
    (OutlineMatch, "raster_mm"): Range(0.05, 5),
    (Ruler, "line_deg"): Range(-180, 180),
    (Ruler, "circle_mm"): POSITIVE,
    (PresentParams, "horizontal_mm_s"): POSITIVE,
    (PresentParams, "incline_pct"): Range(0, 200),
    (PresentParams, "big_advance_mm"): POSITIVE,
    (PresentParams, "small_advance_mm"): POSITIVE,
    (PresentParams, "big_advance_incline_mm"): POSITIVE,
    (LocateParams, "frame_spacing_mm"): POSITIVE,
    (LocateParams, "dedupe_mm"): NON_NEGATIVE,
    (RetrieveParams, "robot_speed_pct"): Range(1, 200),    # 1 %: ui/operate.py MIN_ROBOT_PCT
    (RetrieveParams, "too_far_mm"): POSITIVE,
    (RetrieveParams, "reach_time_s"): NON_NEGATIVE,
    (RetrieveParams, "max_failed_picks"): Range(0, 1000),
    (RetrieveParams, "open_kits"): Range(1, 16),
    (AdjustParams, "period_s"): POSITIVE,
    (ConveyorSpec, "length_mm"): POSITIVE,
    (ConveyorSpec, "width_mm"): POSITIVE,
    (ConveyorSpec, "max_mm_s"): POSITIVE,
    (ConveyorSpec, "accel_mm_s2"): POSITIVE,
    (CellSpec, "return_transit_s"): NON_NEGATIVE,
    (EncoderSpec, "counts_per_mm"): POSITIVE,
    (EncoderSpec, "conveyor_bits"): Range(8, 64),
    (EncoderSpec, "robot_bits"): Range(8, 64),
    (EncoderSpec, "drift_check_s"): Range(0, 60),
    (EncoderSpec, "drift_warn_mm"): POSITIVE,
    (EncoderSpec, "drift_limit_mm"): POSITIVE,
    (EncoderSpec, "robot_sample_s"): Range(0, 0.1),
    (EncoderSpec, "robot_start"): NON_NEGATIVE,
    (HopperSpec, "release_per_mm"): NON_NEGATIVE,
    (HopperSpec, "nominal_fill"): Range(lo=1),
    (CameraSpec, "width_px"): Range(lo=1),
    (CameraSpec, "height_px"): Range(lo=1),
    (CameraSpec, "exposure_ms"): POSITIVE,
    (CameraSpec, "grab_s"): NON_NEGATIVE,
    (CameraSpec, "vision_latency_s"): NON_NEGATIVE,
    (PylonSpec, "gain_db"): Range(0, 48),
    (PylonSpec, "frame_timeout_s"): Range(0.01, 60),
    (PylonSpec, "packet_size"): Range(220, 16404),        # GevSCPSPacketSize, bytes
    (PylonSpec, "inter_packet_delay"): NON_NEGATIVE,      # GevSCPD, ticks
    (PylonSpec, "line_debouncer_us"): Range(0, 1_000_000),  # Basler: 0 to about 1 s
    (PylonSpec, "trigger_delay_us"): Range(0, 10_000_000),  # Basler ace: 0 to 10 s
    (CameraCalibration, "mm_per_px"): POSITIVE,
    (TargetSpec, "max_rms_px"): POSITIVE,
    (TargetSpec, "max_belt_mm"): POSITIVE,
    (TargetSpec, "pitch_mm"): POSITIVE,
    (TargetSpec, "dot_mm"): POSITIVE,
    (TargetSpec, "marker_mm"): NON_NEGATIVE,
    (RenderSpec, "backlight"): GREY,
    (RenderSpec, "falloff"): Range(0, 1),
    (RenderSpec, "part_grey"): GREY,
    (RenderSpec, "belt_grey"): GREY,
    (RenderSpec, "shading"): Range(0, 1),
    (RenderSpec, "highlight"): Range(0, 255),
    (RenderSpec, "noise_sigma"): NON_NEGATIVE,
    (RenderSpec, "blur_px"): NON_NEGATIVE,
    (RobotSpec, "base_deg"): Range(-360, 360),
    (RobotSpec, "reach_mm"): POSITIVE,
    (RobotSpec, "inner_reach_mm"): NON_NEGATIVE,
    (RobotSpec, "v_max_mm_s"): POSITIVE,
    (RobotSpec, "a_max_mm_s2"): POSITIVE,
    (RobotSpec, "approach_mm"): NON_NEGATIVE,
    (RobotSpec, "grip_s"): NON_NEGATIVE,
    (RobotSpec, "release_s"): NON_NEGATIVE,
    (RobotSpec, "track_settle_s"): NON_NEGATIVE,
    (RobotSpec, "grip_tolerance_mm"): POSITIVE,
    (RobotSpec, "command_overhead_s"): NON_NEGATIVE,
    (RobotSpec, "sim_speed_factor"): Range(0.1, 10),
    (LocateParams, "max_parts_per_look"): NON_NEGATIVE,
    (IoSignal, "bit"): NON_NEGATIVE,
    (GalilSpec, "baud"): POSITIVE,
    (GalilSpec, "timeout_s"): POSITIVE,
    (GalilSpec, "latch_input"): Range(1, 8),
    (GalilSpec, "notify_mm"): POSITIVE,
    (GalilSpec, "watchdog_s"): Range(0.2, 60),
    (GalilSpec, "stall_mm"): POSITIVE,
    (GalilSpec, "error_limit_mm"): POSITIVE,
    (GalilSpec, "torque_limit_v"): Range(0.1, 9.9982),
    (GalilSpec, "heartbeat_s"): Range(0.3, 10),
    (AdeptSpec, "motion_port"): Range(1, 65535),
    (AdeptSpec, "position_port"): Range(1, 65535),
    (AdeptSpec, "io_port"): Range(1, 65535),
    (AdeptSpec, "notify_port"): Range(1, 65535),
    (AdeptSpec, "timeout_s"): POSITIVE,
    (AdeptSpec, "motion_timeout_s"): POSITIVE,
    (AdeptSpec, "poll_hz"): Range(1, 200),
    (SimImperfections, "encoder_noise_counts"): NON_NEGATIVE,
    (SimImperfections, "encoder_scale_pct"): Range(-5, 5),
    (SimImperfections, "robot_sample_s"): Range(0, 0.1),
    (SimImperfections, "calib_scale_pct"): Range(-5, 5),
    (SimImperfections, "calib_rotation_deg"): Range(-5, 5),
    (SimImperfections, "land_slide_mm"): NON_NEGATIVE,
    (SimImperfections, "land_turn_deg"): NON_NEGATIVE,
    (SimImperfections, "drop_slide_mm"): NON_NEGATIVE,
    (SimImperfections, "settle_s"): NON_NEGATIVE,
    (SimImperfections, "clump_prob"): Range(0, 1),
    (SimImperfections, "clump_cover_scale"): NON_NEGATIVE,
    (SimImperfections, "clump_zone_mm"): POSITIVE,
    (SimImperfections, "belt_mu_static"): Range(0, 2),
    (SimImperfections, "belt_mu_kinetic"): Range(0, 2),
    (SimImperfections, "grip_p_centre"): Range(0, 1),
    (SimImperfections, "grip_width_mm"): NON_NEGATIVE,
    (SimImperfections, "robot_time_cv"): Range(0, 0.5),
    (SimImperfections, "arm_j1_deg_s"): Range(0, 5000),
    (SimImperfections, "arm_j2_deg_s"): Range(0, 5000),
    (SimImperfections, "arm_z_mm_s"): Range(0, 10000),
    (SimImperfections, "arm_j1_deg_s2"): Range(0, 500000),
    (SimImperfections, "arm_j2_deg_s2"): Range(0, 500000),
    (SimImperfections, "arm_z_mm_s2"): Range(0, 500000),
    # fault plans (feeder_bt.config.faults)
    (FaultRate, "per_pick"): Range(0, 1),
    (FaultRate, "per_frame"): Range(0, 1),
    (FaultRate, "per_hour"): NON_NEGATIVE,
    (FaultRate, "outage_s"): POSITIVE,
    (ScriptedFault, "at_s"): NON_NEGATIVE,
    (ScriptedFault, "release_after_s"): POSITIVE,
    (ScriptedFault, "outage_s"): POSITIVE,
}
ENUMS[(FaultRate, "device")] = COMMS_DEVICES
ENUMS[(ScriptedFault, "device")] = COMMS_DEVICES
ENUMS[(FaultRate, "link")] = LINK_DEATHS
ENUMS[(ScriptedFault, "link")] = LINK_DEATHS
ENUMS[(ScriptedFault, "kind")] = FAULT_KINDS
ENUMS[(ScriptedFault, "phase")] = PHASES
ENUMS[(AdeptSpec, "belt_direction")] = ("forward", "reverse")

#: Adjuster algorithms and the ``adjust.params`` keys each accepts (all optional; an
#: adjuster supplies its own defaults). Keys ending in ``_mm_s`` are horizontal belt speeds
#: and are also checked against the cell's conveyor limits.
ADJUST_PARAMS: dict[str, dict[str, Range]] = {
    "none": {},
    "water_marks": {
        "high": NON_NEGATIVE, "low": NON_NEGATIVE, "gain": POSITIVE, "step": POSITIVE,
        "min_mm_s": POSITIVE, "max_mm_s": POSITIVE, "median_mm_s": POSITIVE,
    },
    "queue_proportional": {
        "target": NON_NEGATIVE, "gain": POSITIVE,
        "min_mm_s": POSITIVE, "max_mm_s": POSITIVE, "nominal_mm_s": POSITIVE,
    },
    "supply_queue": {
        "target_queue": NON_NEGATIVE, "gain_pct": NON_NEGATIVE,
        "min_incline_pct": Range(0, 200), "max_incline_pct": Range(0, 200),
        "horizontal_mm_s": POSITIVE, "pull": Range(0, 1),
        "min_mm_s": POSITIVE, "max_mm_s": POSITIVE,
    },
}
ADJUST_ALGORITHMS: tuple[str, ...] = tuple(ADJUST_PARAMS)
ENUMS[(AdjustParams, "algorithm")] = ADJUST_ALGORITHMS
# a vibratory-plate cell (core/plate_model.py)
ENUMS[(CellSpec, "presentation")] = ("belt", "plate")
ENUMS[(PlatePolicy, "policy")] = ("smart", "fixed")
for _f in ("feed_reps", "flip_reps", "dispense_reps"):
    RANGES[(PlatePolicy, _f)] = Range(1, 10)            # AnyFeeder Guide Table 3-2: [turns]
RANGES[(PlatePolicy, "purge_reps")] = Range(1, 127)     # Table 3-2: purge 1...127
RANGES[(PlatePolicy, "fixed_every")] = Range(1, 100)
for _f in ("feed_mm_per_rep", "rep_s", "dispense_per_rep", "purge_mm_per_rep", "timeout_s"):
    RANGES[(PlateSpec, _f)] = POSITIVE
RANGES[(PlateSpec, "flip_prob")] = Range(0, 1)
for _f in ("quiet_s", "echo_probe_s"):
    RANGES[(PlateSpec, _f)] = POSITIVE
for _f in ("feed_forward", "feed_backward", "flip_forward", "flip_backward", "flip",
           "dispense", "purge"):
    RANGES[(PlateSpeeds, _f)] = Range(1, 10)            # Table 3-2: [speed]
for _f in ("feed_forward", "feed_backward", "flip_forward", "flip_backward", "flip",
           "dispense", "heavy_dispense"):
    RANGES[(PlateRepetitions, _f)] = Range(1, 10)       # Table 3-2: [turns]
RANGES[(PlateRepetitions, "purge")] = Range(1, 127)

#: Ordering constraints between adjuster parameters: (algorithm, smaller, larger, strict).
ADJUST_ORDER: tuple[tuple[str, str, str, bool], ...] = (
    ("water_marks", "low", "high", True),
    ("water_marks", "min_mm_s", "median_mm_s", False),
    ("water_marks", "median_mm_s", "max_mm_s", False),
    ("water_marks", "min_mm_s", "max_mm_s", False),
    ("queue_proportional", "min_mm_s", "nominal_mm_s", False),
    ("queue_proportional", "nominal_mm_s", "max_mm_s", False),
    ("queue_proportional", "min_mm_s", "max_mm_s", False),
    ("supply_queue", "min_incline_pct", "max_incline_pct", False),
    ("supply_queue", "min_mm_s", "horizontal_mm_s", False),
    ("supply_queue", "horizontal_mm_s", "max_mm_s", False),
    ("supply_queue", "min_mm_s", "max_mm_s", False),
)

LEAF_RE = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*$")

# Model fields that are not YAML keys of their class (filled by a special builder or the
# loader). Fields typed ``Path`` are always loader-filled.
_IMPLIED_FIELDS: dict[type, frozenset[str]] = {CellSpec: frozenset({"return_transit_s"}),
                                               Scenario: frozenset({"overlay_path"})}
# YAML keys that are not model fields (read by the loader itself).
_EXTRA_KEYS: dict[type, frozenset[str]] = {Scenario: frozenset({"cell"})}


def _num(v: float) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)
