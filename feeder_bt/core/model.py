"""The scenario and cell models: what the YAML files mean once validated.

``loader.py`` builds these from YAML and reports every problem as ``FILE:LINE: key: what``.
Units are in the names: ``_mm``, ``_mm_s``, ``_s``, ``_pct``, ``_deg``, ``_px``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from feeder_bt.core.plate_model import PlatePolicy, PlateSpec

# ---------------------------------------------------------------------------- parts


@dataclass
class Shape:
    """A part's outline in its own frame, origin at the outline's area centroid.

    ``kind`` is ``disc`` (``diameter_mm``, optional ``hole_mm``: a washer), ``rect``
    (``size_mm``) or ``polygon`` (``points_mm``, convex or not, optional ``holes_mm``: a
    list of polygons inside it); the loader recentres polygons on the area centroid of
    the region (holes taken out).
    """

    kind: str
    diameter_mm: float = 0.0
    size_mm: tuple[float, float] = (0.0, 0.0)
    points_mm: list[tuple[float, float]] = field(default_factory=list)
    hole_mm: float = 0.0
    holes_mm: list[list[tuple[float, float]]] = field(default_factory=list)


@dataclass
class StablePose:
    name: str
    probability: float
    pickable: bool
    mirror: bool = False                 # lies on its other face: silhouette mirrored
    silhouette: Shape | None = None      # None: the part's own outline


@dataclass
class PlacePose:
    x: float
    y: float
    z: float = 0.0
    orient: bool = False                 # rotate the part to angle 0 when placing


@dataclass
class Grip:
    """One place the gripper may take a part, in the part's own frame (origin at the area
    centroid, angle 0 as drawn; mirrored with the part when it lies face-down)."""

    offset_mm: tuple[float, float] = (0.0, 0.0)
    angle_deg: float = 0.0               # the gripper's turn from the part's angle 0


@dataclass
class Finger:
    """A finger of the gripper: a box in the grip's frame (x along the grip's angle)."""

    offset_mm: tuple[float, float]       # the box's centre
    size_mm: tuple[float, float]         # its extent along x and y


@dataclass
class PickSpec:
    """Where a part is gripped and what the gripper needs clear around it: the
    locator offers the first grip whose footprint (the cup, or the fingers, grown by
    ``clearance_mm``) is clear of every other blob; the simulator judges a grip over a
    hole, or whose footprint lies on a neighbour, as a miss."""

    grips: list[Grip] = field(default_factory=lambda: [Grip()])
    cup_radius_mm: float = 0.0           # a suction cup's radius (0: none)
    fingers: list[Finger] = field(default_factory=list)
    clearance_mm: float = 1.0


@dataclass
class PartSpec:
    name: str
    shape: Shape
    poses: dict[str, StablePose]
    place: PlacePose
    tool_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation_tolerance_deg: float = 5.0
    # The outline looks the same turned by 360/symmetry degrees (a chain-link
    # plate: 2, a square: 4, a hex nut: 6), and, with mirror_symmetric, turned over; angles
    # are then only defined (placed, judged, searched) modulo 360/symmetry
    symmetry: int = 1
    mirror_symmetric: bool = False
    pick: PickSpec | None = None         # None: gripped at the area centroid, nothing checked
    # wear: the most times a part may travel the belt; one that falls off the end
    # on its last pass goes to scrap (parts.scrapped) instead of back to the hopper; 0: no limit
    max_passes: int = 0
    # the simulated cell only (hal/sim/slip.py): this part's friction on the belt; 0: the
    # cell's sim.belt_mu_static / sim.belt_mu_kinetic
    belt_mu_static: float = 0.0
    belt_mu_kinetic: float = 0.0

    def belt_friction(self, sim: SimImperfections) -> tuple[float, float]:
        """Static and kinetic friction of this part on the simulated belt: its own
        ``belt_mu_*``, or (0) the cell's ``sim.belt_mu_*``."""
        return (self.belt_mu_static or sim.belt_mu_static,
                self.belt_mu_kinetic or sim.belt_mu_kinetic)

    @property
    def period_deg(self) -> float:
        """The turn after which the part looks the same: 360 / ``symmetry``."""
        return 360.0 / self.symmetry


# ---------------------------------------------------------------------------- vision


@dataclass
class Threshold:
    method: str = "fixed"                # fixed | otsu | adaptive
    value: float = 40.0                  # fixed: grey-level difference
    block_px: int = 51                   # adaptive: neighbourhood (odd, px)
    # adaptive: OpenCV's C, subtracted from the local mean (so < 0: foreground is that far
    # above the mean of the image in which parts are bright)
    c: float = -5.0


@dataclass
class Morphology:
    open_px: int = 0
    close_px: int = 0


@dataclass
class VisionClass:
    """A feature box: a blob whose features all fall in the ranges is this part in this pose."""

    part: str
    pose: str
    pickable: bool
    ranges: dict[str, tuple[float, float]] = field(default_factory=dict)  # feature -> [lo, hi]
    mirrored: bool | None = None         # for chiral outlines (cut_corner): face seen
    rulers: dict[str, tuple[float, float]] = field(default_factory=dict)  # ruler -> [lo, hi]
    # how this class's angle is read (``VisionRecipe.orientation``'s values); None: the
    # recipe's. A screw's head end and a nut's hexagon need different readings in one recipe
    orientation: str | None = None


@dataclass
class Ruler:
    """A gauge laid on a blob's outline from its centroid (the thesis's "linear and circular
    rulers", 8.2.1.6): exactly one of the two is given."""

    # a line through the centroid at this angle to the blob's long axis: the distance
    # between the outline's outermost edges along it, mm
    line_deg: float | None = None
    # a circle of this radius about the centroid: how many separate arcs of it lie on the
    # part (a sprocket's teeth, a connector's pins)
    circle_mm: float | None = None


@dataclass
class OutlineMatch:
    """How ``orientation: outline`` judges a match (``vision.outline``): a part whose
    outline the camera draws coarsely (a thin screw) needs a lower ``min_iou`` or a finer
    raster than a plate does."""

    min_iou: float = 0.75                # a best overlap under this is no match
    margin: float = 0.04                 # the best must beat every other pose by this much
    raster_mm: float = 0.5               # the cell of the raster the overlap is counted on


@dataclass
class VisionRecipe:
    backlight: bool = True
    golden_image: bool = True
    foreground: str = "dark"             # dark | light: parts darker or brighter than the belt
    threshold: Threshold = field(default_factory=Threshold)
    morphology: Morphology = field(default_factory=Morphology)
    min_area_mm2: float = 100.0
    min_hole_mm2: float = 3.0            # smaller holes in a blob are not counted (specks)
    rulers: dict[str, Ruler] = field(default_factory=dict)   # named gauges, for classes
    classes: list[VisionClass] = field(default_factory=list)
    # none | cut_corner | principal_axis | outline | moment (a class may have its own)
    orientation: str = "none"
    outline_match: OutlineMatch = field(default_factory=OutlineMatch)
    # offer only grips whose footprint is clear of other blobs (``PartSpec.pick``);
    # false: offer the first grip whatever is beside it (to measure what the check saves)
    check_clearance: bool = True
    # cut blobs that fit no class into parts (distance transform, watershed: vision.split)
    split_touching: bool = False
    leaf: str | None = None              # "pkg.mod:Class": a locator class used instead of ours


# ---------------------------------------------------------------------------- behaviour


@dataclass
class PresentParams:
    mode: str = "continuous"             # continuous | incremental
    horizontal_mm_s: float = 150.0
    incline_pct: float = 40.0            # inclined speed as % of horizontal
    big_advance_mm: float = 1100.0       # incremental: load the horizontal belt
    small_advance_mm: float = 240.0      # incremental: about half the camera window
    big_advance_incline_mm: float = 400.0
    plate: PlatePolicy = field(default_factory=PlatePolicy)   # a plate cell


@dataclass
class LocateParams:
    frame_spacing_mm: float = 300.0
    dedupe_mm: float = 12.0
    max_parts_per_look: int = 0          # 0: every part found; 1: the original feeder's "GO"
    leaf: str | None = None              # "pkg.mod:Class": a leaf used instead of the recipe step


@dataclass
class RetrieveParams:
    policy: str = "fifo"                 # fifo | earliest_deadline | shortest_cycle | lookahead
    robot_speed_pct: float = 100.0
    tracking: bool = True
    too_far_mm: float = 1190.0
    reach_time_s: float = 0.35           # expected time from decision to grip, for too_far
    sequence: list[str] = field(default_factory=list)   # optional part-type order (a kit in order)
    # a kit (thesis 8.2.1.5): part types and how many of each, placed in any order; the
    # retrieve tree takes what the kit lacks next and the report counts kits (kits.py)
    kit: dict[str, int] = field(default_factory=dict)
    # kits built at once (trays at the station): a part goes to the fullest open kit that
    # lacks it, so the robot need not wait for the one type the only open kit lacks
    open_kits: int = 1
    leaf: str | None = None              # "pkg.mod:Class": a leaf used instead of the pick step
    # price picks with the robot model fitted online from measured move times
    # (feeder_bt/robot/fit.py); false: with the cell's nominal model (the fit is still reported)
    learn_robot: bool = True
    # picks failed (missed, out of reach) since the last part placed before the cell calls
    # the operator (FAULT): a wrong robot frame or a gripper with no vacuum; 0: never
    max_failed_picks: int = 20


@dataclass
class AdjustParams:
    algorithm: str = "none"              # none | water_marks | queue_proportional
    period_s: float = 0.5
    params: dict[str, float] = field(default_factory=dict)
    leaf: str | None = None              # "pkg.mod:Class": an Adjuster used instead of algorithm


@dataclass
class Scenario:
    name: str
    path: Path
    cell_path: Path
    parts: dict[str, PartSpec]
    hopper: dict[str, int]
    vision: VisionRecipe
    present: PresentParams = field(default_factory=PresentParams)
    locate: LocateParams = field(default_factory=LocateParams)
    retrieve: RetrieveParams = field(default_factory=RetrieveParams)
    adjust: AdjustParams = field(default_factory=AdjustParams)
    tick_hz: float = 50.0
    overlay_path: Path | None = None     # the overlay merged in (loader-filled, not a key)


# ---------------------------------------------------------------------------- cell


@dataclass
class ConveyorSpec:
    length_mm: float = 1219.0
    width_mm: float = 610.0
    max_mm_s: float = 400.0
    accel_mm_s2: float = 1500.0


@dataclass
class CameraCalibration:
    """Pixel (u, v) -> belt frame (x, y) in mm, at the latch.

    x = origin_x + mm_per_px * (v cos r - u sin r)... see ``feeder_bt.vision.pixels``.
    """

    origin_mm: tuple[float, float] = (80.0, -15.0)
    mm_per_px: float = 1.0
    rotation_deg: float = 0.0
    # the lens (``feeder calibrate camera`` with several views): focal lengths and principal
    # point in px, and OpenCV's distortion coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]);
    # pixels are undistorted before they are mapped to the belt
    intrinsics: tuple[float, float, float, float] | None = None
    dist: list[float] = field(default_factory=list)
    # undistorted pixel -> belt mm as a 3x3 homography, row by row (a tilted camera); when
    # set it replaces the similarity above, which is then its nearest similarity (for scale)
    homography: list[float] | None = None


@dataclass
class RenderSpec:
    """How the simulated camera draws frames (``feeder_bt.sim.render``)."""

    lighting: str = "backlit"            # backlit | frontlit
    backlight: float = 225.0             # backlit: grey of the lit, empty belt
    falloff: float = 0.22                # vignetting: brightness lost in the corners
    part_grey: float = 40.0              # the parts' grey (frontlit: of their lit top)
    noise_sigma: float = 3.0
    blur_px: float = 0.8
    belt_grey: float = 35.0              # frontlit: grey of the empty belt
    shading: float = 0.35                # frontlit: brightness a part loses at its edges
    highlight: float = 70.0              # frontlit: grey levels a highlight adds


@dataclass
class TargetSpec:
    """The cell's calibration target (``feeder calibrate camera``; see
    ``feeder_bt.calibration.targets`` for the kinds and their points)."""

    kind: str = "chessboard"             # chessboard | circles | acircles | charuco
    board: tuple[int, int] = (8, 12)     # points per row and rows (inner corners, dots)
    pitch_mm: float = 40.0               # square side; dots' spacing along a row
    dot_mm: float = 14.0                 # circle grids: dot diameter
    marker_mm: float = 0.0               # charuco: marker side (0: 0.7 of the square)
    dictionary: str = "DICT_4X4_250"     # charuco: OpenCV's ArUco dictionary
    # `feeder calibrate camera` refuses (writes nothing) a lens model whose reprojection
    # rms is over max_rms_px, or a belt plane whose rms is over max_belt_mm
    max_rms_px: float = 1.0
    max_belt_mm: float = 0.3


@dataclass
class PylonSpec:
    """A GenICam camera through Basler's pylon (``camera.source: pylon:SERIAL``), set with
    the GenICam standard feature names, SFNC 2 or the older SFNC 1 ones, whichever the
    camera offers (docs/real-cell.md, "An industrial camera"). The
    exposure is ``camera.exposure_ms`` (ExposureTime), the size ``width_px`` x ``height_px``."""

    trigger: str = "Software"            # TriggerSource of FrameStart: Software | Line1
    gain_db: float = 0.0                 # Gain
    pixel_format: str = "Mono8"          # PixelFormat: Mono8 | Mono10 | Mono12 | Mono16
    frame_timeout_s: float = 1.0         # a trigger with no frame after this: a lost frame
    # trigger Line1..3: the cell's I/O output (``io:``) pulsed once per grab, wired to the
    # camera's line and to the Galil latch input; None: the pulse comes from elsewhere
    trigger_signal: str | None = None
    # GigE only (left as the camera has them when None): GevSCPSPacketSize in bytes (jumbo
    # frames need the NIC's MTU to match) and GevSCPD, the inter-packet delay in ticks
    packet_size: int | None = None
    inter_packet_delay: int | None = None
    # a line trigger only (Line1..3): the edge that starts a frame (TriggerActivation; it
    # must be the edge the Galil latches, opto-coupler inversion included), the line's
    # debouncer (LineDebouncerTime, SFNC 1 LineDebouncerTimeAbs) and the FrameStart
    # trigger delay (TriggerDelay, SFNC 1 TriggerDelayAbs), both in microseconds and left
    # as the camera has them when None; both delay the exposure after the latched pulse
    trigger_activation: str = "RisingEdge"
    line_debouncer_us: float | None = None
    trigger_delay_us: float | None = None
    # an emulated camera only (PYLON_CAMEMU): a folder of images it serves in name order
    # (ImageFilename, ImageFileMode On), relative to the cell file; recorded frames or a
    # rendered target through the vendor SDK without a camera
    emulator_images: str | None = None


@dataclass
class CameraSpec:
    width_px: int = 640
    height_px: int = 484
    exposure_ms: float = 2.0
    grab_s: float = 0.040
    vision_latency_s: float = 0.030      # virtual time a recipe takes on a fast run
    calibration: CameraCalibration = field(default_factory=CameraCalibration)
    # simulated cell only: how the simulated camera really maps (None: exactly as calibrated)
    sim_truth: CameraCalibration | None = None
    calibration_file: str | None = None  # YAML replacing `calibration` (calibration.files)
    # real cell only: "0" (a device index), a stream URL, a folder of images or a video file
    source: str = "0"
    pylon: PylonSpec = field(default_factory=PylonSpec)   # camera.source: pylon:SERIAL
    render: RenderSpec = field(default_factory=RenderSpec)
    target: TargetSpec | None = None     # the calibration target (None: --target's default)


@dataclass
class RobotSpec:
    model: str = "cobra600"
    base_mm: tuple[float, float] = (1370.0, 305.0)
    # the robot base's turn in the cell frame: a point p in the robot's own world frame is
    # Rot(base_deg) p + base_mm in the cell frame (vplus/PROTOCOL.md "Frames"; sent as FRAME)
    base_deg: float = 0.0
    reach_mm: float = 600.0
    inner_reach_mm: float = 160.0
    v_max_mm_s: float = 4000.0
    a_max_mm_s2: float = 21000.0
    approach_mm: float = 25.0
    grip_s: float = 0.060
    release_s: float = 0.040
    track_settle_s: float = 0.030
    safe_mm: tuple[float, float] = (1370.0, -150.0)
    grip_tolerance_mm: float = 4.0
    # the calibrated base pose (commission adept writes it; calibration.files), and the
    # cell-frame points the person touches for it (empty: three spread over the pick window)
    frame_file: str | None = None
    touch_points_mm: list[tuple[float, float]] = field(default_factory=list)
    # the belt window (belt-frame x, mm): where the arm may track the belt, and past which no
    # pick starts; sent to the robot controller at connect (V+ WINDOW), taught with the tool
    # at commissioning. Unset: ``belt_window`` derives them from the reach over the belt
    # (the pick limit: the downstream limit).
    belt_window_mm: tuple[float, float] | None = None
    pick_limit_mm: float | None = None
    # controller time per pick and per place before the arm moves: command round trips,
    # program start-up (0 for our V+ servers, which get one line per pick or place)
    command_overhead_s: float = 0.0
    # simulated cell only: the simulated arm's true speed over the one described here (v_max
    # times f, a_max times f squared: every move takes 1/f as long). The controller never reads
    # it; it is how a test or a study makes the robot slower or faster than the cell says.
    sim_speed_factor: float = 1.0


@dataclass
class EncoderSpec:
    counts_per_mm: float = 20.0
    conveyor_bits: int = 32
    robot_bits: int = 24
    robot_start: int = 0
    # the in-run re-check of the two counters (encoder.DriftWatch); 0 s turns it off
    drift_check_s: float = 1.0          # seconds between samples
    drift_warn_mm: float = 1.0          # an ``encoder_drift`` warning event
    drift_limit_mm: float = 3.0         # the cell faults: picks land this far off
    # how often the robot controller samples its belt channel (V+'s trajectory cycle, 16 ms
    # on older controllers): a BELT read is up to this old, half of it on average, and the
    # drift check allows for it. Check at commissioning (docs/real-cell.md).
    robot_sample_s: float = 0.016


@dataclass
class HopperSpec:
    release_per_mm: float = 0.030
    nominal_fill: int = 150


@dataclass
class IoSignal:
    controller: str
    bit: int
    dir: str = "out"                     # in | out
    active_low: bool = False             # the input reads 0 while the signal is active
    active: str = "high"                 # high | low: the level at which the signal is active


@dataclass
class GalilSpec:
    """The conveyors' motion controller (``--hal emulated|real``)."""

    url: str = "socket://127.0.0.1:23"   # a serial port (/dev/ttyS0) or socket://HOST:PORT
    baud: int = 115200                   # serial ports only
    timeout_s: float = 2.0               # a reply slower than this is a lost connection
    axes: dict[str, str] = field(default_factory=lambda: {"incline": "A", "horizontal": "B"})
    latch_axis: str = "B"                # the axis whose encoder the camera trigger latches
    # digital input wired to the camera trigger (thesis 2.3); the DMC-21x3's latch inputs are
    # fixed per axis (input 1 latches A ... 8 latches H), so None means latch_axis's own
    latch_input: int | None = None
    programs: list[str] = field(default_factory=lambda: ["monitor.dmc"])  # in galil_programs/
    notify_mm: float = 5.0               # distance notifier period on the latch axis
    # --- safe reconnects (docs/real-cell.md, "The Galil controller")
    rtscts: bool = False                 # serial ports: RTS/CTS hardware handshake
    servo_on: str = "never"              # never | start | reconnect: when the driver may SH
    free_handles: str = "ours"           # ours | others | none: IH clean-up at connect
    watchdog_s: float = 1.0              # host silent this long: the card stops the belts
    off_on_error: bool = True            # OE 1 on our axes: motor off on a position error
    stall_mm: float = 1.0                # jogging, encoder moved less than this in 2 s: stall
    # --- stops that stop (docs/real-cell.md, "Safety settings sent at connect")
    error_limit_mm: float = 5.0          # ER: position error (mm) that trips the off-on-error
    torque_limit_v: float = 5.0          # TL: continuous motor command limit, volts (TK 0)
    limit_switches: str = "low"          # CN n0: the level of an active limit switch: low | high
    latch_edge: str = "falling"          # CN n2: the latch input's edge: falling | rising
    inputs: int = 8                      # digital inputs on the card: 8 (1-4 axes) | 16 (5-8)
    heartbeat_s: float = 1.0             # #INMON silent this long: a cell FAULT, belts stopped


@dataclass
class AdeptSpec:
    """The robot controller running the V+ servers of ``vplus/``."""

    host: str = "127.0.0.1"
    motion_port: int = 1401
    position_port: int = 1402
    io_port: int = 1403
    notify_port: int = 1404
    timeout_s: float = 5.0               # connect/reply time-out for short commands
    # the longest a pick, place or move may take at 100 % speed (longer in proportion at
    # a lower speed): past it the reply is lost, as in a half-open link (a pulled cable)
    motion_timeout_s: float = 6.0
    # may RECOVER turn arm power on after a servo fault (else: the operator); never after
    # an e-stop or a guard took it (PowerOff: always a person)
    recover_power_on: bool = False
    belt_direction: str = "forward"      # the robot's belt channel counts: forward | reverse
    poll_hz: float = 50.0                # position poller rate (POLL: pose and belt count)


@dataclass
class SimImperfections:
    """What makes the simulated cell imperfect (``sim/imperfect.py``); every figure
    and its source is in docs/simulator.md. ``ideal: true`` turns them all off; a zero
    turns off one."""

    ideal: bool = False
    # encoders (both counters count the same belt encoder)
    encoder_noise_counts: float = 0.5    # sigma of a reading, counts, before rounding
    encoder_scale_pct: float = 0.1       # true counts/mm differ from the cell's by this
    robot_sample_s: float = 0.016        # the robot's belt channel: sampled and held
    # the camera's true mapping against the cell's calibration
    calib_offset_mm: tuple[float, float] = (0.5, -0.4)
    calib_scale_pct: float = 0.1
    calib_rotation_deg: float = 0.1
    # the lens and the mounting (docs/simulator.md): an 8 mm lens on a 1/2" 640-px sensor
    # (10 um pixels: 800 px focal length), a little barrel distortion, the camera a degree
    # or so off square to the belt; added to a camera described as a similarity only
    lens_focal_px: float = 800.0
    lens_k1: float = -0.03
    lens_k2: float = 0.0
    tilt_deg: tuple[float, float] = (1.5, -1.0)
    # landing on the horizontal belt (off the ramp, or dropped by the robot)
    land_slide_mm: float = 2.0           # sigma of the slide along and across
    land_turn_deg: float = 3.0           # sigma of the turn while settling
    drop_slide_mm: float = 4.0           # the same for a part the robot drops
    settle_s: float = 0.25               # the slide's duration
    clump_prob: float = 0.01             # a part lands against or on the one before it
    # ... more often the more of the landing zone (the belt's first clump_zone_mm) parts
    # already cover: p = clump_prob + (1 - clump_prob) (1 - exp(-cover / scale))
    clump_cover_scale: float = 0.8       # 0: the chance stays clump_prob
    clump_zone_mm: float = 150.0
    # belt friction (slip.py): parts slide when the belt speeds up or brakes harder than
    # belt_mu_static * g; kinetic friction brings them back to the belt's speed
    belt_mu_static: float = 0.30
    belt_mu_kinetic: float = 0.22
    # grip: P(success) = grip_p_centre / (1 + exp((d - d50) / width)), d50 = the cell's
    # robot.grip_tolerance_mm
    grip_p_centre: float = 0.995
    grip_width_mm: float = 0.5
    # robot: each move's time is the nominal one times 1 + N(0, cv)
    robot_time_cv: float = 0.02
    # the world's arm (robot/scara.py), its true joint limits; 0: the Cobra 600 shape timed
    # to the cell's robot description (v_max, a_max), as a cell file without a world does
    arm_j1_deg_s: float = 0.0
    arm_j2_deg_s: float = 0.0
    arm_z_mm_s: float = 0.0
    arm_j1_deg_s2: float = 0.0
    arm_j2_deg_s2: float = 0.0
    arm_z_mm_s2: float = 0.0


@dataclass
class CellSpec:
    name: str
    path: Path
    hal: str = "sim"                     # sim | emulated | real
    conveyors: dict[str, ConveyorSpec] = field(default_factory=lambda: {
        "horizontal": ConveyorSpec(), "incline": ConveyorSpec()})
    return_transit_s: float = 12.0
    encoder: EncoderSpec = field(default_factory=EncoderSpec)
    hopper: HopperSpec = field(default_factory=HopperSpec)
    camera: CameraSpec = field(default_factory=CameraSpec)
    robot: RobotSpec = field(default_factory=RobotSpec)
    io: dict[str, IoSignal] = field(default_factory=dict)
    galil: GalilSpec = field(default_factory=GalilSpec)
    adept: AdeptSpec = field(default_factory=AdeptSpec)
    sim: SimImperfections = field(default_factory=SimImperfections)   # simulated cell only
    presentation: str = "belt"           # belt | plate (docs/plate-feeders.md)
    plate: PlateSpec = field(default_factory=PlateSpec)


def reach_over_belt(cell: CellSpec) -> tuple[float, float]:
    """The stretch of the horizontal belt (belt-frame x, mm) some point of which, across its
    width, is inside the arm's reach: the widest belt window the arm can work."""
    r = cell.robot
    bx, by = r.base_mm
    conv = cell.conveyors.get("horizontal")
    width = conv.width_mm if conv else 610.0
    length = conv.length_mm if conv else 1219.0
    dy = 0.0 if 0.0 <= by <= width else min(abs(by), abs(by - width))
    half = math.sqrt(max(r.reach_mm ** 2 - dy ** 2, 0.0))
    return max(bx - half, 0.0), min(bx + half, length)


def belt_window(cell: CellSpec) -> tuple[float, float, float]:
    """(upstream, downstream, pick limit), belt-frame x in mm: the cell description's
    ``robot.belt_window_mm`` and ``robot.pick_limit_mm``, else the reach over the belt, and
    the downstream limit as the pick limit (a part that would leave the window before its
    grip fails there, on the controller as in the simulator)."""
    r = cell.robot
    up, down = r.belt_window_mm if r.belt_window_mm is not None else reach_over_belt(cell)
    pick = r.pick_limit_mm if r.pick_limit_mm is not None else down
    return float(up), float(down), float(pick)
