"""The dashboard's camera view: the last frame with what the locator made of it.

Threading: the locate behaviour only hands a reference to each frame and its result to a
``LatestLook`` slot (``vision.latest``); nothing is drawn or encoded on the tick thread.
``CameraFeed.picture()`` runs in the web server's thread pool when a page asks: it takes
the latest look, draws the located parts (class and pose; x, y and angle in the belt
frame; an arrow along the angle) and the rejected blobs with the reason each was
rejected, and encodes a JPEG with OpenCV. One picture serves every page; a new one is
made at most ``camera_fps`` times a second (a frame that comes sooner is skipped), and a
session asking more often than that is refused (429), so the view costs a few encodes
a second whatever the number of pages.

The JSON answer lists exactly what was drawn (``parts``, ``rejected``), so that a test or
a script can check the picture against the locator's result for that frame.
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
from starlette.concurrency import run_in_threadpool
from starlette.requests import HTTPConnection, Request
from starlette.responses import Response
from starlette.routing import Route

from feeder_bt.ui.responses import json_response, refuse
from feeder_bt.vision.latest import KEY, LatestLook, Look
from feeder_bt.vision.overlay import draw
from feeder_bt.vision.pixels import Calibration

JPEG_QUALITY = 80


@dataclass(frozen=True)
class Picture:
    """One encoded frame and the JSON that says what is drawn on it."""

    seq: int
    jpeg: bytes
    meta_json: str


class CameraFeed:
    """Makes ``Picture``s from the latest look, at most once per ``min_interval_s``.

    ``slot`` is filled by the locate behaviour once ``install`` has put it in a cell's
    context; ``calibration`` (the cell's) draws the angle arrows."""

    def __init__(self, slot: LatestLook, calibration: Calibration | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.slot, self.calibration, self.clock = slot, calibration, clock
        self._lock = threading.Lock()          # one encode at a time, in a pool thread
        self._picture: Picture | None = None
        self._made_at = -math.inf
        self.encodes = 0

    def install(self, ctx: Any) -> None:
        """On the tick thread after each tick: make the current context's locate behaviour
        hand its frames to our slot (a new context comes with every start)."""
        if ctx is not None and ctx.extras.get(KEY) is not self.slot:
            ctx.extras[KEY] = self.slot

    def latest(self) -> Picture | None:
        """The picture made last, without making one."""
        return self._picture

    def picture(self, min_interval_s: float) -> Picture | None:
        """The latest frame's picture: made now if there is a newer frame and the last
        picture is at least ``min_interval_s`` old, else the one made last. Blocking
        (drawing and encoding take a few ms): call it off the event loop."""
        with self._lock:
            look = self.slot.get()
            pic = self._picture
            if look is None or (pic is not None and look.seq == pic.seq):
                return pic
            now = self.clock()
            if pic is not None and now < self._made_at + min_interval_s:
                return pic
            self._picture = self._make(look)
            self._made_at = now
            self.encodes += 1
            return self._picture

    def _make(self, look: Look) -> Picture:
        img, parts, rejected = draw(look.frame.image, look.result, self.calibration)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise RuntimeError("OpenCV could not encode the camera picture")
        h, w = img.shape[:2]
        meta = {"seq": look.seq, "frame": look.frame.index, "t": round(look.frame.t, 3),
                "width": w, "height": h, "vision_ms": round(float(look.result.ms), 1),
                "image": f"/api/camera/{look.seq}.jpg", "parts": parts, "rejected": rejected}
        return Picture(look.seq, buf.tobytes(), json.dumps(meta, separators=(",", ":")))


def frame_seq(name: str) -> int | None:
    """``SEQ.jpg`` to SEQ; None for anything else. Parsed by hand, bounded before the
    conversion: a route's ``{seq:int}`` converts any run of digits, and 4,301 of them
    raise inside the router (a 500)."""
    stem, dot, ext = name.partition(".")
    if ext != "jpg" or not dot or not 1 <= len(stem) <= 18 or not stem.isascii() \
            or not stem.isdigit():
        return None
    return int(stem)


class Pacer:
    """A token bucket per session: ``rate`` requests a second, ``burst`` at once."""

    MAX_KEYS = 256

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self.clock = clock
        self._buckets: dict[str, tuple[float, float]] = {}     # key -> (tokens, at)

    def wait_s(self, key: str, rate: float, burst: float = 2.0) -> float:
        """0 and one token taken if ``key`` may go now; else how long until it may."""
        now = self.clock()
        tokens, at = self._buckets.get(key, (burst, now))
        tokens = min(burst, tokens + (now - at) * rate)
        if tokens < 1.0:
            self._buckets[key] = (tokens, now)
            return (1.0 - tokens) / rate
        self._buckets[key] = (tokens - 1.0, now)
        if len(self._buckets) > self.MAX_KEYS:            # forget the long-idle
            self._buckets = {k: v for k, v in self._buckets.items() if now - v[1] < 60.0}
        return 0.0


class CameraView:
    """The routes: ``GET /api/camera`` (what is drawn, and where the picture is) and
    ``GET /api/camera/{seq}.jpg`` (the picture), for signed-in users only.

    ``watcher`` gives the caller's session without counting the request as use (the page
    polls: a forgotten tab must not keep its session alive); ``fps`` the setting now."""

    def __init__(self, feed: CameraFeed | None,
                 watcher: Callable[[HTTPConnection], Any],
                 fps: Callable[[], float], clock: Callable[[], float] = time.monotonic) -> None:
        self.feed, self.watcher, self.fps = feed, watcher, fps
        self.pacer = Pacer(clock)
        self.routes = [Route("/api/camera", self.meta),
                       Route("/api/camera/{name}", self.image)]

    def _gate(self, request: Request, what: str) -> Any:
        """The session, or the refusal to send back."""
        s = self.watcher(request)
        if s is None:
            return refuse("not logged in", 401)
        if self.feed is None:
            return refuse("no camera view in this run", 404)
        wait = self.pacer.wait_s(f"{s.token}:{what}", self.fps())
        if wait > 0:
            secs = max(1, math.ceil(wait))
            return refuse(f"at most {self.fps():g} camera frames a second: try again "
                          f"in {wait:.2f} s", 429, {"retry-after": str(secs)})
        return s

    async def meta(self, request: Request) -> Response:
        got = self._gate(request, "meta")
        if isinstance(got, Response):
            return got
        assert self.feed is not None
        pic = await run_in_threadpool(self.feed.picture, 1.0 / self.fps())
        if pic is None:
            return json_response({"ok": True, "fps": self.fps(), "seq": None,
                                  "why": "no frame located yet (the cell grabs frames "
                                         "while it feeds)"})
        head = f'{{"ok":true,"fps":{self.fps():g},'
        return Response(head + pic.meta_json[1:], media_type="application/json",
                        headers={"cache-control": "no-store"})

    async def image(self, request: Request) -> Response:
        got = self._gate(request, "image")
        if isinstance(got, Response):
            return got
        assert self.feed is not None
        pic = self.feed.latest()
        seq = frame_seq(request.path_params.get("name", ""))
        if pic is None or seq is None or pic.seq != seq:
            return refuse("that frame is gone: ask /api/camera for the latest", 404)
        return Response(pic.jpeg, media_type="image/jpeg",
                        headers={"cache-control": "private, max-age=60"})
