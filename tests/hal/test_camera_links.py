"""Camera links that die slowly: a stream server that accepts and says nothing, and an
emulated camera that drips a byte at a time or answers garbage. Each fails in about its
own time-out with a typed error naming the camera, never OpenCV's 30 s or a plain Python
error, and never a hang."""

from __future__ import annotations

import socket
import threading
import time

import pytest

from feeder_bt.core.errors import CommsLost, ConfigError, GrabFailed
from feeder_bt.emulators.camera_server import CameraClient
from feeder_bt.hal.camera.sources import VideoCaptureSource

GENEROUS_S = 15.0      # far under OpenCV's own 30 s and a drip's 48 minutes, on any machine


def _server(reply) -> tuple[int, list]:
    """A loopback server; ``reply(conn)`` runs for each connection."""
    srv = socket.create_server(("127.0.0.1", 0))
    held: list = [srv]

    def accept() -> None:
        while True:
            try:
                conn, _ = srv.accept()
            except OSError:
                return
            held.append(conn)
            threading.Thread(target=reply, args=(conn,), daemon=True).start()

    threading.Thread(target=accept, daemon=True).start()
    return srv.getsockname()[1], held


def _close(held) -> None:
    for s in held:
        s.close()


def test_a_silent_stream_server_fails_the_open_in_its_time_out():
    port, held = _server(lambda conn: None)          # accepts, never answers
    try:
        t0 = time.monotonic()
        with pytest.raises(ConfigError, match="cannot open camera"):
            VideoCaptureSource(f"http://127.0.0.1:{port}/video", timeout_s=1.0)
        assert time.monotonic() - t0 < GENEROUS_S
    finally:
        _close(held)


def test_an_emulated_camera_that_drips_fails_the_frame_as_a_lost_link():
    def drip(conn) -> None:
        conn.recv(64)
        try:
            for b in b"OK 640 484\n":
                conn.sendall(bytes([b]))
                time.sleep(0.3)
        except OSError:
            pass
    port, held = _server(drip)
    try:
        cam = CameraClient(f"emulated-camera://127.0.0.1:{port}", timeout_s=1.0)
        t0 = time.monotonic()
        with pytest.raises(CommsLost, match="no whole frame within 1 s"):
            cam.capture()
        assert time.monotonic() - t0 < GENEROUS_S
        cam.close()
    finally:
        _close(held)


@pytest.mark.parametrize("reply,error,text", [
    (b"OK 640\n", GrabFailed, "bad reply"),
    (b"OK 100000 100000\n", GrabFailed, "100000 x 100000"),
    (b"x" * 200, CommsLost, "no reply line in 64 bytes"),
])
def test_garbage_from_an_emulated_camera_is_a_typed_error(reply, error, text):
    def answer(conn) -> None:
        conn.recv(64)
        conn.sendall(reply)
    port, held = _server(answer)
    try:
        cam = CameraClient(f"emulated-camera://127.0.0.1:{port}", timeout_s=2.0)
        with pytest.raises(error, match=text):
            cam.capture()
        cam.close()
    finally:
        _close(held)


def test_no_emulated_camera_there_is_a_lost_link():
    port, held = _server(lambda conn: None)
    _close(held)                                     # nobody listens any more
    with pytest.raises(CommsLost, match="cannot connect"):
        CameraClient(f"emulated-camera://127.0.0.1:{port}", timeout_s=1.0)
