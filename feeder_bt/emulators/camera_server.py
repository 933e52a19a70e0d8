"""The emulated camera as a server, for ``feeder commission camera`` in another process.

One TCP socket on loopback; a client sends ``GRAB`` and gets ``OK W H`` followed by
``W*H`` bytes of grey image. A grab fires the plant's camera trigger (so the Galil
emulator latches the belt's count at that instant, the wiring of thesis section 2.3) and
renders what lies under the camera at the instant of exposure: the calibration target the
person laid on the stopped belt, or the marker riding the belt, or else the plant's belt.
``exposure_delay_s`` is the camera's true delay from trigger to exposure, which the
timing step of commissioning must find (0: exposure at the trigger).

The renderings go through the simulated camera's *truth* calibration; the client sees
only pixels.
"""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np

from feeder_bt.calibration.camera import Target, TargetPose
from feeder_bt.core.errors import CommsLost, GrabFailed, one_line
from feeder_bt.emulators.camera import PlantCameraSource
from feeder_bt.emulators.line_server import LineServer
from feeder_bt.sim.imperfect import true_calibration
from feeder_bt.sim.realtime import Plant
from feeder_bt.sim.render import Renderer
from feeder_bt.sim.target import TargetCamera

MARKER_MM = 20.0            # diameter of the round calibration marker the person puts down


class CameraScene:
    """What the person laid under the camera: a target (stopped belt) or a marker (riding
    the horizontal belt). Every method is thread-safe."""

    def __init__(self, plant: Plant, exposure_delay_s: float = 0.0, seed: int = 1) -> None:
        self.plant = plant
        self.delay_s = exposure_delay_s
        self.seed = seed
        truth = true_calibration(plant.cell)
        self._targets = TargetCamera(plant.cell.camera, truth, seed=seed)
        self._renderer = Renderer(plant.cell.camera, truth)
        self._belt = PlantCameraSource(plant)
        self._lock = threading.Lock()
        self.target: tuple[Target, TargetPose] | None = None
        self.marker: tuple[float, float, float] | None = None   # x, y, belt position then
        self.frames = 0

    def _belt_mm(self, t: float | None = None) -> float:
        with self.plant.lock:
            t = self.plant.world.now() if t is None else t
            return self.plant.world.horizontal.pos(t)

    def lay_target(self, target: Target | None, pose: TargetPose | None = None) -> None:
        with self._lock:
            self.target = None if target is None or pose is None else (target, pose)
            self._targets.place(target, pose)

    def put_marker(self, x_mm: float, y_mm: float) -> None:
        with self._lock:
            self.marker = (x_mm, y_mm, self._belt_mm())

    def take_marker(self) -> None:
        with self._lock:
            self.marker = None

    def grab(self) -> np.ndarray:
        """Trigger and expose: one grey frame."""
        with self._lock:
            target, marker = self.target, self.marker
            self.frames += 1
            index = self.frames
        if target is None and marker is None:
            return self._belt.capture()
        t = self.plant.trigger()
        if target is not None:
            return self._targets.grab().result.image
        x0, y0, p0 = marker                                    # type: ignore[misc]
        x = x0 + self._belt_mm(t + self.delay_s) - p0          # where it is at exposure
        ring = [(x + MARKER_MM / 2 * math.cos(a), y0 + MARKER_MM / 2 * math.sin(a))
                for a in np.linspace(0.0, 2 * math.pi, 48, endpoint=False)]
        rng = np.random.default_rng([self.seed, index])
        return self._renderer.render([np.array(ring)], rng)


class CameraServer(LineServer):
    """Serves ``CameraScene.grab`` on a socket, one client at a time."""

    thread_name = "camera-emu"

    def __init__(self, scene: CameraScene, host: str = "127.0.0.1", port: int = 0) -> None:
        self.scene = scene
        super().__init__(host, port)

    def on_line(self, conn: socket.socket, line: bytes) -> None:
        verb = line.decode("ascii", "replace").strip().upper()
        if verb == "GRAB":
            img = np.ascontiguousarray(self.scene.grab(), dtype=np.uint8)
            h, w = img.shape[:2]
            conn.sendall(f"OK {w} {h}\n".encode() + img.tobytes())
        elif verb:
            conn.sendall(f"ERR unknown request {verb[:20]!r}\n".encode())


class CameraClient:
    """A ``FrameSource`` (``capture``/``close``) on ``emulated-camera://HOST:PORT``.

    Every capture has one deadline (``timeout_s``) for the whole frame, so a server that
    drips a byte every few seconds fails it as surely as a silent one; its header line is
    capped; every failure is a typed ``CommsLost`` or ``GrabFailed`` naming the server."""

    SCHEME = "emulated-camera://"
    HEAD_CAP = 64                  # "OK <w> <h>\n" is far shorter
    MAX_PIXELS = 16_000_000

    def __init__(self, spec: str, timeout_s: float = 10.0) -> None:
        self.where = spec
        self.timeout_s = timeout_s
        host, _, port = spec[len(self.SCHEME):].partition(":")
        try:
            self.sock = socket.create_connection((host, int(port)), timeout=timeout_s)
        except (OSError, ValueError) as e:
            raise CommsLost(f"{spec}: cannot connect: {e}") from None
        self._buf = b""

    def _recv(self, deadline: float) -> bytes:
        left = deadline - time.monotonic()
        if left <= 0:
            raise CommsLost(f"{self.where}: no whole frame within {self.timeout_s:g} s")
        self.sock.settimeout(left)
        try:
            chunk = self.sock.recv(1 << 20)
        except TimeoutError:
            raise CommsLost(f"{self.where}: no whole frame within {self.timeout_s:g} s") \
                from None
        except OSError as e:
            raise CommsLost(f"{self.where}: link lost: {e}") from None
        if not chunk:
            raise CommsLost(f"{self.where}: the server closed the link")
        return chunk

    def capture(self) -> np.ndarray:
        deadline = time.monotonic() + self.timeout_s
        try:
            self.sock.sendall(b"GRAB\n")
        except OSError as e:
            raise CommsLost(f"{self.where}: link lost: {e}") from None
        while b"\n" not in self._buf:
            if len(self._buf) > self.HEAD_CAP:
                raise CommsLost(f"{self.where}: no reply line in {self.HEAD_CAP} bytes")
            self._buf += self._recv(deadline)
        line, _, self._buf = self._buf.partition(b"\n")
        head = line.decode("ascii", "replace").split()
        if len(head) != 3 or head[0] != "OK" or not (head[1].isdigit() and head[2].isdigit()):
            raise GrabFailed(f"{self.where}: bad reply {one_line(' '.join(head))[:60]!r}")
        w, h = int(head[1]), int(head[2])
        if not 0 < w * h <= self.MAX_PIXELS:
            raise GrabFailed(f"{self.where}: an image of {w} x {h} pixels")
        while len(self._buf) < w * h:
            self._buf += self._recv(deadline)
        data, self._buf = self._buf[:w * h], self._buf[w * h:]
        return np.frombuffer(data, np.uint8).reshape(h, w).copy()

    def close(self) -> None:
        self.sock.close()
