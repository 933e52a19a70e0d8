"""The latest frame and what the locator made of it, for whoever wants to show it.

The locate behaviour hands over a *reference* to each frame and its result (no copy, no
drawing, no encoding: nothing that could slow the tick); a reader on another thread (the
operator UI's camera view) takes the latest one when it wants it and does the work there.
The frame's image is never written after the grab, and the result is not changed after
``Enqueue`` has read it, so sharing the references is safe.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from feeder_bt.hal.interfaces import Frame

KEY = "latest_look"            # where the slot sits in ``Ctx.extras`` when someone watches


@dataclass(frozen=True)
class Look:
    """One frame and the locator's result on it; ``seq`` rises with every hand-over."""

    seq: int
    frame: Frame
    result: Any                 # vision.locator.LocateResult (or a custom locator's)


class LatestLook:
    """A latest-value slot: one writer (the tick thread), any number of readers.

    ``put`` is one reference assignment; readers see either the old or the new ``Look``."""

    def __init__(self) -> None:
        self._look: Look | None = None
        self._seq = 0

    def put(self, frame: Frame, result: Any) -> None:
        self._seq += 1
        self._look = Look(self._seq, frame, result)

    def get(self) -> Look | None:
        return self._look


def hand_over(extras: dict[str, Any], frame: Frame, result: Any) -> None:
    """From the locate behaviour: give the frame to the slot if somebody installed one."""
    slot = extras.get(KEY)
    if slot is not None:
        slot.put(frame, result)
