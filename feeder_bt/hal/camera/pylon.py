"""A GenICam camera through Basler's pylon (``camera.source: pylon:SERIAL``, or ``pylon:``
for the first camera found); ``pip install -e '.[pylon]'``.

Set with the GenICam standard feature names (SFNC): FrameStart ``TriggerMode On`` with
``TriggerSource`` Software or Line1 (and for a line its ``TriggerActivation``, debouncer
and trigger delay), the exposure, the gain, ``PixelFormat``, and for GigE
``GevSCPSPacketSize`` / ``GevSCPD``. Older GigE cameras (SFNC 1.x, e.g. the ace GigE) name
some features otherwise (``ExposureTimeAbs``, ``GainRaw``, ``TriggerDelayAbs``,
``LineDebouncerTimeAbs``): each setting takes the first of its names (``FEATURES``) that
the camera's node map offers writable.

Each grab is paired with one trigger by count and, where the camera counts its frames, by
its frame counter (the grab result's block id; on GigE it wraps from 65535 to 1, and 0
means the camera has none: then the pairing is by order alone): a frame left over from an
extra trigger is drained before the next trigger and counted (``extra_triggers``); a
failed buffer, a trigger with no frame or a gap in the counter drops the pair
(``GrabFailed``, counted in ``lost_frames``) and re-synchronises, so a latch is never
paired with another trigger's image. The pylon camera emulator (``PYLON_CAMEMU=N``, see
docs/real-cell.md) answers the same features; what it does not do is said there.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np

from feeder_bt.core.errors import ConfigError, GrabFailed
from feeder_bt.core.model import PylonSpec
from feeder_bt.hal.camera.sources import as_frame

SCHEME = "pylon:"
INSTALL_HINT = "pip install -e '.[pylon]' (Basler's pypylon)"

#: A setting by its SFNC 2 name, then its SFNC 1 names (Basler, "SFNC Standard: What Is
#: Migration Mode"; the ace GigE manual sets ExposureTimeAbs, GainRaw, TriggerDelayAbs
#: and LineDebouncerTimeAbs): the first the camera offers writable is the one set.
#: ``GainAbs`` is in dB like ``Gain``; ``GainRaw`` counts model-specific steps. No frame
#: rate is set (AcquisitionFrameRate, SFNC 1 AcquisitionFrameRateAbs): every frame is
#: triggered.
FEATURES: dict[str, tuple[str, ...]] = {
    "ExposureTime": ("ExposureTime", "ExposureTimeAbs"),          # microseconds
    "Gain": ("Gain", "GainAbs", "GainRaw"),
    "TriggerDelay": ("TriggerDelay", "TriggerDelayAbs"),          # microseconds
    "LineDebouncerTime": ("LineDebouncerTime", "LineDebouncerTimeAbs"),   # microseconds
}

#: pylon's grab result block ids (PylonGrabResult_t.BlockID): on GigE without the
#: extended id mode they start at 1 and wrap at 65535 (so 1 follows 65535); 0 means the
#: camera does not count its frames; UINT64_MAX marks an invalid id.
GIGE_BLOCK_ID_MAX = 65535
BLOCK_ID_INVALID = 2 ** 64 - 1
GIGE_CLASS = "BaslerGigE"
#: without ``WaitForFrameTriggerReady``: how long a stray frame may still be on its way
#: after its exposure (readout and transfer) before the drain looks for it
SETTLE_S = 0.05
TRANSFER_MS = 20      # longest a finished frame takes to reach the host (GigE: a 640 x 484
                      # mono frame is 0.3 MB, 3 ms at 1 Gbit/s; the rest is host latency)


def block_id_follows(last: int, block: int, gige: bool) -> bool:
    """Whether ``block`` is the frame right after ``last``: one more, or 1 after 65535 on
    GigE (the 16-bit counter wraps and skips 0, which means "no counter")."""
    return block == last + 1 or (gige and last == GIGE_BLOCK_ID_MAX and block == 1)


def expected_block_id(last: int, gige: bool) -> int:
    """The block id the frame after ``last`` should carry (for the one-line message)."""
    return 1 if gige and last == GIGE_BLOCK_ID_MAX else last + 1


def load_pylon():
    """pypylon's ``pylon`` and ``genicam`` modules, or a one-line ConfigError saying how
    to install them. Imported here only: a cell without a pylon camera never loads it."""
    try:
        from pypylon import genicam, pylon
    except ImportError as e:
        raise ConfigError(f"pylon: pypylon is not installed ({e}); {INSTALL_HINT}",
                          key="camera.source") from None
    return pylon, genicam


def list_cameras() -> list[dict[str, str]]:
    """Every camera pylon enumerates (GigE, USB3, and emulated ones with PYLON_CAMEMU)."""
    pylon, _ = load_pylon()
    return [{"serial": d.GetSerialNumber(), "model": d.GetModelName(),
             "class": d.GetDeviceClass()}
            for d in pylon.TlFactory.GetInstance().EnumerateDevices()]


class PylonSource:
    """One pylon camera, triggered per grab. ``before_trigger`` runs just before each
    trigger (the emulated cell renders the belt there, at the pulse the Galil latches);
    ``line_pulse`` fires the line for ``trigger: Line1`` (None: the pulse comes from the
    wiring, and a grab waits ``frame_timeout_s`` for it)."""

    def __init__(self, spec: str, settings: PylonSpec, exposure_ms: float,
                 size: tuple[int, int] | None = None,
                 before_trigger: Callable[[], None] | None = None,
                 line_pulse: Callable[[], None] | None = None,
                 configure: Callable[[object], None] | None = None) -> None:
        self.pylon, self.genicam = load_pylon()
        self.spec, self.settings = spec, settings
        self.before_trigger, self.line_pulse = before_trigger, line_pulse
        self.lock = threading.RLock()     # capture() may call prepare()
        self.frames = self.lost_frames = self.extra_triggers = 0
        self.last_id: int | None = None          # the camera's block id of the last frame
        self.counted = True       # False: its block ids do not count (0): paired by order
        self.names: dict[str, str] = {}          # FEATURES key -> the name this camera has
        self.last_error = ""
        self.reopened = 0
        self._prepared = False
        self.exposure_ms, self.size, self.configure = exposure_ms, size, configure
        self.cam = self._open(spec[len(SCHEME):].strip())
        self._set_up()

    def _set_up(self) -> None:
        try:
            self._configure(self.exposure_ms, self.size)
            if self.configure is not None:
                self.configure(self.cam)           # the emulated cell's image files
            self._start()
        except (self.genicam.GenericException, ConfigError) as e:
            self.cam.Close()          # a camera left open would refuse the next opener
            if isinstance(e, ConfigError):
                raise
            raise ConfigError(f"{self.spec}: {_one_line(e)}", key="camera.pylon") from None

    # ---------------------------------------------------------------- set-up
    def _open(self, serial: str):
        pylon = self.pylon
        tl = pylon.TlFactory.GetInstance()
        devices = tl.EnumerateDevices()
        found = [d for d in devices if not serial or d.GetSerialNumber() == serial]
        if not found:
            seen = ", ".join(d.GetSerialNumber() for d in devices) or "none"
            raise ConfigError(f"{self.spec}: no such pylon camera (cameras found: {seen}; "
                              "PYLON_CAMEMU=N adds N emulated ones)", key="camera.source")
        try:
            cam = pylon.InstantCamera(tl.CreateDevice(found[0]))
            cam.Open()
        except self.genicam.GenericException as e:
            raise ConfigError(f"{self.spec}: cannot open: {_one_line(e)}",
                              key="camera.source") from None
        self.serial = found[0].GetSerialNumber()
        self.model = found[0].GetModelName()
        self.device_class = found[0].GetDeviceClass()
        self.counted = True
        return cam

    @property
    def gige(self) -> bool:
        return self.device_class == GIGE_CLASS

    def _node(self, name: str):
        """The camera's feature ``name`` when it is there and writable, else None."""
        node = self.cam.GetNodeMap().GetNode(name)
        return node if node is not None and self.genicam.IsWritable(node) else None

    def _has(self, name: str) -> bool:
        return self._node(name) is not None

    def feature(self, key: str) -> str | None:
        """The name this camera has for the ``FEATURES`` setting ``key`` (SFNC 2 first)."""
        if key not in self.names:
            found = next((n for n in FEATURES[key] if self._has(n)), None)
            if found is None:
                return None
            self.names[key] = found
        return self.names[key]

    def _set_feature(self, key: str, value: object) -> None:
        """A ``FEATURES`` setting under whichever of its names the camera has."""
        name = self.feature(key)
        if name is None:
            raise ConfigError(f"{self.spec}: the camera has no writable "
                              f"{' nor '.join(FEATURES[key])}", key="camera.pylon")
        self._set(name, value)

    def _set(self, name: str, value: object) -> None:
        """One feature by its name; a camera without it, or refusing the value, is a
        one-line ConfigError naming the feature."""
        node = self._node(name)
        if node is None:
            raise ConfigError(f"{self.spec}: the camera has no writable {name}",
                              key="camera.pylon")
        if hasattr(node, "GetSymbolics") and isinstance(value, str) \
                and value not in node.GetSymbolics():
            raise ConfigError(f"{self.spec}: {name} {value!r} is not one of the camera's: "
                              f"{', '.join(node.GetSymbolics())}", key="camera.pylon")
        try:
            node.Value = value
        except self.genicam.GenericException as e:
            raise ConfigError(f"{self.spec}: {name} {value!r}: {_one_line(e)}",
                              key="camera.pylon") from None

    def _configure(self, exposure_ms: float, size: tuple[int, int] | None) -> None:
        s = self.settings
        self.names = {}                  # a camera reopened may be another model
        if size is not None:
            self._set("Width", int(size[0]))
            self._set("Height", int(size[1]))
        self._set("PixelFormat", s.pixel_format)
        self._set("TriggerSelector", "FrameStart")
        self._set("TriggerMode", "On")
        self._set("TriggerSource", s.trigger)
        if s.trigger != "Software":
            self._configure_line(s.trigger)
        if self._has("ExposureAuto"):
            self._set("ExposureAuto", "Off")
        self._set_feature("ExposureTime", float(exposure_ms) * 1000.0)   # microseconds
        self._configure_gain(float(s.gain_db))
        if s.emulator_images is not None:
            if self.device_class != "BaslerCamEmu":
                raise ConfigError(f"{self.spec}: emulator_images: only an emulated camera "
                                  f"(PYLON_CAMEMU) serves files; this is a {self.device_class}",
                                  key="camera.pylon")
            self._set("TestImageSelector", "Off")
            self._set("ImageFilename", s.emulator_images)
            self._set("ImageFileMode", "On")
        if s.packet_size is not None:
            self._set("GevSCPSPacketSize", int(s.packet_size))
        if s.inter_packet_delay is not None:
            self._set("GevSCPD", int(s.inter_packet_delay))

    def _configure_line(self, line: str) -> None:
        """A line trigger: its edge, the FrameStart trigger delay (TriggerSelector is
        FrameStart already), the line's debouncer."""
        s = self.settings
        self._set("TriggerActivation", s.trigger_activation)
        if s.trigger_delay_us is not None:
            self._set_feature("TriggerDelay", float(s.trigger_delay_us))
        if s.line_debouncer_us is not None:
            self._set("LineSelector", line)
            self._set_feature("LineDebouncerTime", float(s.line_debouncer_us))

    def _configure_gain(self, gain_db: float) -> None:
        """Gain in dB (``Gain``, SFNC 1 ``GainAbs``). A camera with only ``GainRaw`` counts
        model-specific steps (the dB of a step is in the model's manual): it takes
        ``gain_db: 0`` as its least gain, and refuses any other in one line."""
        if self._has("GainAuto"):
            self._set("GainAuto", "Off")
        sel = self._node("GainSelector")
        if sel is not None and "All" in sel.GetSymbolics():
            self._set("GainSelector", "All")
        if self.feature("Gain") != "GainRaw":
            self._set_feature("Gain", gain_db)
            return
        if gain_db != 0:
            raise ConfigError(f"{self.spec}: gain_db {gain_db:g}: this camera sets its gain "
                              "only as GainRaw, in steps its model's manual gives; set "
                              "gain_db: 0 (its least gain)", key="camera.pylon")
        self._set("GainRaw", int(self._node("GainRaw").GetMin()))

    def exposure_us(self) -> float:
        """The exposure the camera really has, read back, in microseconds."""
        name = self.feature("ExposureTime")
        if name is None:
            raise ConfigError(f"{self.spec}: the camera has no ExposureTime",
                              key="camera.pylon")
        return float(self.cam.GetNodeMap().GetNode(name).Value)

    def trigger_lag_us(self) -> float:
        """How long after the line's pulse (the one the Galil latches) the exposure
        starts, from the cell's settings: the debouncer plus the trigger delay."""
        s = self.settings
        if s.trigger == "Software":
            return 0.0
        return float(s.line_debouncer_us or 0.0) + float(s.trigger_delay_us or 0.0)

    def _start(self) -> None:
        """Start the stream afresh: its block ids begin again at 0."""
        if self.cam.IsGrabbing():
            self.cam.StopGrabbing()
        self.cam.StartGrabbing(self.pylon.GrabStrategy_OneByOne)
        self.last_id = None

    # ---------------------------------------------------------------- grabbing
    def capture(self) -> np.ndarray:
        """Trigger once and return that trigger's frame; ``GrabFailed`` (one line) when
        the frame is lost, late or not this trigger's — the pair is dropped, never
        mis-paired."""
        with self.lock:
            try:
                return self._capture()
            except GrabFailed as e:
                self.last_error = str(e)
                raise
            except self.genicam.GenericException as e:
                if self._gone():                   # it went away during this grab
                    try:
                        self._reopen()
                    except GrabFailed as gone:
                        self.last_error = str(gone)
                        raise
                self.lost_frames += 1
                self.last_error = f"camera {self.spec}: {_one_line(e)}"
                raise GrabFailed(self.last_error) from None

    def prepare(self) -> int:
        """Before the latch is armed: wait until the camera can take a trigger (a frame
        still exposing or in transfer has then reached the host) and drop every frame
        nobody asked for (an extra trigger pulse, a late frame), counting them; the first
        frame after this is the next trigger's own. A camera that cannot say when it is
        ready (``CanWaitForFrameTriggerReady`` false) is given the exposure, the line's
        delays and ``SETTLE_S`` instead; the drain itself needs nothing of the camera.
        ``LatchedCamera`` calls it before ``AL``; a bare ``capture`` calls it itself."""
        with self.lock:
            self._prepared = True
            cam = self.cam
            try:
                if not cam.IsOpen() or cam.IsCameraDeviceRemoved() or not cam.IsGrabbing():
                    return 0
            except self.genicam.GenericException:
                return 0                     # the grab that follows says what is wrong
            self._wait_ready()
            n = 0
            try:
                while n < 1000:              # bounded: a free-running camera never empties
                    # the first wait covers a frame the camera has finished but is still
                    # sending (ready for a trigger is not yet delivered to the host)
                    wait_ms = TRANSFER_MS if n == 0 else 0
                    r = cam.RetrieveResult(wait_ms, self.pylon.TimeoutHandling_Return)
                    if not r.IsValid():
                        break
                    self.last_id = r.GetBlockID()
                    r.Release()
                    n += 1
            except self.genicam.GenericException:
                pass                         # the grab that follows says what is wrong
            self.extra_triggers += n
            return n

    def _wait_ready(self) -> bool:
        """Until the camera can take a frame trigger; False when it did not say so in
        ``frame_timeout_s``."""
        cam, timeout_s = self.cam, self.settings.frame_timeout_s
        try:
            if cam.CanWaitForFrameTriggerReady():
                return bool(cam.WaitForFrameTriggerReady(int(timeout_s * 1000),
                                                         self.pylon.TimeoutHandling_Return))
        except self.genicam.GenericException:
            pass                             # claimed, then refused: wait as without it
        try:
            exposure_s = self.exposure_us() / 1e6
        except (self.genicam.GenericException, ConfigError):
            exposure_s = 0.0
        time.sleep(min(timeout_s, exposure_s + self.trigger_lag_us() / 1e6 + SETTLE_S))
        return True

    def _gone(self) -> bool:
        try:
            return not self.cam.IsOpen() or self.cam.IsCameraDeviceRemoved()
        except self.genicam.GenericException:
            return True

    def _reopen(self) -> None:
        """The camera went away (closed, unplugged, powered off): this grab fails with one
        line; the camera is opened again by serial if it is back, else the next grab
        tries again (the locate tree's fallback decides when that is a FAULT)."""
        self.lost_frames += 1
        gone = f"camera {self.spec}: the camera is gone (closed or unplugged)"
        try:
            self.cam.DestroyDevice()
        except self.genicam.GenericException:
            pass
        try:
            self.cam = self._open(self.serial)
            self._set_up()
        except ConfigError as e:
            raise GrabFailed(f"{gone}; reopening: {e.what}") from None
        self.reopened += 1
        raise GrabFailed(f"{gone}; reopened, the next grab uses it")

    def _reapply(self) -> None:
        """The camera was set otherwise behind the cell's back: the cell's settings again."""
        try:
            self.cam.StopGrabbing()
            self._set_up()
        except ConfigError as e:
            raise GrabFailed(f"camera {self.spec}: setting it up again: {e.what}") from None

    def _capture(self) -> np.ndarray:
        cam, pylon = self.cam, self.pylon
        if self._gone():
            self._reopen()
        if not self._prepared:
            self.prepare()
        self._prepared = False
        cam = self.cam
        timeout_ms = int(self.settings.frame_timeout_s * 1000)
        if self.before_trigger is not None:
            self.before_trigger()
        if self.settings.trigger == "Software":
            if not self._wait_ready():
                self.lost_frames += 1
                raise GrabFailed(f"camera {self.spec}: not ready for a trigger in "
                                 f"{self.settings.frame_timeout_s:g} s")
            cam.ExecuteSoftwareTrigger()
        elif self.line_pulse is not None:
            self.line_pulse()
        r = cam.RetrieveResult(timeout_ms, pylon.TimeoutHandling_Return)
        if not r.IsValid():
            self.lost_frames += 1
            self._start()            # a late frame must not answer the next trigger
            raise GrabFailed(f"camera {self.spec}: trigger with no frame in "
                             f"{self.settings.frame_timeout_s:g} s ({self.settings.trigger})")
        try:
            if not r.GrabSucceeded():
                self.lost_frames += 1
                self.last_id = r.GetBlockID()
                raise GrabFailed(f"camera {self.spec}: frame {r.GetBlockID()} lost: "
                                 f"{_one_line(r.GetErrorDescription())}")
            fmt = self._pixel_format(r)
            img = r.GetArray().copy() if fmt == self.settings.pixel_format else None
            if img is not None:
                block = r.GetBlockID()
                expected = self._counter_gap(block)
                if expected is not None:
                    self.lost_frames += 1
                    raise GrabFailed(f"camera {self.spec}: frame counter {block}, expected "
                                     f"{expected}: pair dropped, re-synced")
        finally:
            r.Release()
        if img is None:
            self.lost_frames += 1
            self._reapply()
            raise GrabFailed(f"camera {self.spec}: pixel format {fmt}, the cell expects "
                             f"{self.settings.pixel_format}: settings sent again")
        self.frames += 1
        return as_frame(img)

    def _counter_gap(self, block: int) -> int | None:
        """The block id this frame should have carried when it breaks the count (a frame
        went missing), else None. A GigE camera's 0 says it has no counter, as does a
        counter standing still at 0: from then on frames pair by order alone (the drain
        before each trigger, the stream restart after a time-out)."""
        last, self.last_id = self.last_id, block
        if not self.counted:
            return None
        if block == BLOCK_ID_INVALID:
            self.last_id = None              # this one frame's id is unusable
            return None
        if (self.gige and block == 0) or (block == 0 and last == 0):
            self.counted = False
            return None
        if last is None or block_id_follows(last, block, self.gige):
            return None
        return expected_block_id(last, self.gige)

    def _pixel_format(self, r) -> str:
        names = {getattr(self.pylon, f"PixelType_{f}"): f
                 for f in ("Mono8", "Mono10", "Mono12", "Mono16")}
        pt = r.GetPixelType()
        return names.get(pt, f"pixel type 0x{int(pt):x}")

    def counts(self) -> dict[str, int]:
        """For the report and the tests: frames delivered, pairs dropped, extra triggers."""
        return {"frames": self.frames, "lost_frames": self.lost_frames,
                "extra_triggers": self.extra_triggers}

    def close(self) -> None:
        with self.lock:
            try:
                if self.cam.IsGrabbing():
                    self.cam.StopGrabbing()
                self.cam.Close()
            except self.genicam.GenericException:
                pass


def _one_line(e: object) -> str:
    """pylon's messages run on with the file and line of its C++ source: the first clause."""
    text = str(e).splitlines()[0] if str(e) else type(e).__name__
    return text.split(" : ")[0].strip()
