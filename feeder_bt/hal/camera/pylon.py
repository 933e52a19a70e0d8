"""A GenICam camera through Basler's pylon (``camera.source: pylon:SERIAL``, or ``pylon:``
for the first camera found); ``pip install -e '.[pylon]'``.

Set with the GenICam standard feature names (SFNC): FrameStart ``TriggerMode On`` with
``TriggerSource`` Software or Line1, ``ExposureTime``, ``Gain``, ``PixelFormat``, and for
GigE ``GevSCPSPacketSize`` / ``GevSCPD``. Each grab is paired with one trigger by count
and by the camera's own frame counter (the grab result's block id): a frame left over from
an extra trigger is drained before the next trigger and counted (``extra_triggers``); a
failed buffer, a trigger with no frame or a gap in the counter drops the pair
(``GrabFailed``, counted in ``lost_frames``) and re-synchronises, so a latch is never
paired with another trigger's image. The pylon camera emulator (``PYLON_CAMEMU=N``, see
docs/real-cell.md) answers the same features; what it does not do is said there.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from feeder_bt.core.errors import ConfigError, GrabFailed
from feeder_bt.core.model import PylonSpec
from feeder_bt.hal.camera.sources import as_frame

SCHEME = "pylon:"
INSTALL_HINT = "pip install -e '.[pylon]' (Basler's pypylon)"


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
        return cam

    def _set(self, name: str, value: object) -> None:
        """One feature by its SFNC name; a camera without it, or refusing the value, is a
        one-line ConfigError naming the feature."""
        g = self.genicam
        node = self.cam.GetNodeMap().GetNode(name)
        if node is None or not g.IsWritable(node):
            raise ConfigError(f"{self.spec}: the camera has no writable {name}",
                              key="camera.pylon")
        if hasattr(node, "GetSymbolics") and isinstance(value, str) \
                and value not in node.GetSymbolics():
            raise ConfigError(f"{self.spec}: {name} {value!r} is not one of the camera's: "
                              f"{', '.join(node.GetSymbolics())}", key="camera.pylon")
        try:
            getattr(self.cam, name).Value = value
        except self.genicam.GenericException as e:
            raise ConfigError(f"{self.spec}: {name} {value!r}: {_one_line(e)}",
                              key="camera.pylon") from None

    def _configure(self, exposure_ms: float, size: tuple[int, int] | None) -> None:
        s = self.settings
        if size is not None:
            self._set("Width", int(size[0]))
            self._set("Height", int(size[1]))
        self._set("PixelFormat", s.pixel_format)
        self._set("TriggerSelector", "FrameStart")
        self._set("TriggerMode", "On")
        self._set("TriggerSource", s.trigger)
        if self._has("ExposureAuto"):
            self._set("ExposureAuto", "Off")
        self._set("ExposureTime", float(exposure_ms) * 1000.0)      # SFNC: microseconds
        if self._has("GainAuto"):
            self._set("GainAuto", "Off")
        self._set("Gain", float(s.gain_db))
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

    def _has(self, name: str) -> bool:
        node = self.cam.GetNodeMap().GetNode(name)
        return node is not None and self.genicam.IsWritable(node)

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
        frame after this is the next trigger's own. ``LatchedCamera`` calls it before
        ``AL``; a bare ``capture`` calls it itself."""
        with self.lock:
            self._prepared = True
            cam = self.cam
            if not cam.IsOpen() or cam.IsCameraDeviceRemoved() or not cam.IsGrabbing():
                return 0
            try:
                cam.WaitForFrameTriggerReady(int(self.settings.frame_timeout_s * 1000),
                                             self.pylon.TimeoutHandling_Return)
                n = 0
                while cam.NumReadyBuffers.Value > 0:
                    r = cam.RetrieveResult(0, self.pylon.TimeoutHandling_Return)
                    if not r.IsValid():
                        break
                    self.last_id = r.GetBlockID()
                    r.Release()
                    n += 1
            except self.genicam.GenericException:
                return 0                     # the grab that follows says what is wrong
            self.extra_triggers += n
            return n

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
            if not cam.WaitForFrameTriggerReady(timeout_ms, pylon.TimeoutHandling_Return):
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
                expected = None if self.last_id is None else self.last_id + 1
                self.last_id = block
                if expected is not None and block != expected:
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
