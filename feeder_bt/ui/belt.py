"""The dashboard's belt view: the horizontal belt in plan, from the controller's
own data — never the simulator's. On a plate cell the same view shows the plate
(``geometry["plate"]``) and the parts queued on it, which do not move.

Where the parts are is what the cell believes: each queued part's pose at its latch, moved
by the belt travel since then as the robot controller's belt encoder counts it
(``Part.x_at``, the same reckoning the retriever uses to decide ``too_far``). The camera
window is the image's corners through the cell's calibration; the robot's window is its
reach (an annulus about its base) and the scenario's ``too_far_mm``. Built on the tick
thread at each publish, as plain data in the status (``status["belt"]``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from feeder_bt.behaviours.keys import RETRIEVE
from feeder_bt.control.cell import Cell
from feeder_bt.core.parts import Part
from feeder_bt.vision.pixels import Calibration

MAX_PARTS = 200                 # a queue longer than this is shown by its first parts


def _r(v: float) -> float:
    return round(float(v), 1)


class BeltPanel:
    """Follows one cell's queue and encoder for the page; every method on the tick thread."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        spec = cell.cell
        conv = spec.conveyors["horizontal"]
        cam = spec.camera
        cal = Calibration(cam.calibration)
        w, h = cam.width_px, cam.height_px
        corners = cal.px_to_mm(np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5],
                                         [-0.5, h - 0.5]]))
        length, width, plate = conv.length_mm, conv.width_mm, None
        if spec.presentation == "plate":     # a plate cell: the plate in the same frame
            (px, py), (pl, pw) = spec.plate.origin_mm, spec.plate.size_mm
            plate = {"origin_mm": [_r(px), _r(py)], "size_mm": [_r(pl), _r(pw)]}
            length = px + pl + 40.0
            width = max(py + pw, spec.robot.base_mm[1]) + 40.0
        self.geometry = {
            "length_mm": _r(length), "width_mm": _r(width), "plate": plate,
            "camera": [[_r(x), _r(y)] for x, y in corners],
            "robot": {"base_mm": [_r(v) for v in spec.robot.base_mm],
                      "reach_mm": _r(spec.robot.reach_mm),
                      "inner_reach_mm": _r(spec.robot.inner_reach_mm)},
        }

    def _part(self, p: Part, x: float) -> dict[str, Any]:
        area = p.features.get("area_mm2")
        return {"id": p.id, "type": p.type, "pose": p.pose, "x_mm": _r(x), "y_mm": _r(p.y_mm),
                "angle_deg": _r(p.angle_deg),
                "r_mm": _r((area / np.pi) ** 0.5) if area else None}

    def snapshot(self) -> dict[str, Any]:
        """The geometry, the queued parts where they are now, and the part being picked."""
        ctx = self.cell.ctx
        out: dict[str, Any] = {**self.geometry, "too_far_mm": None, "encoder": None,
                               "parts": [], "picking": None}
        if ctx is None:
            return out
        out["too_far_mm"] = _r(ctx.scenario.retrieve.too_far_mm)
        try:
            count = int(ctx.hal.robot_position.belt_encoder())
        except Exception:            # a controller that cannot answer now: no positions
            return out
        enc = self.cell.cell.encoder
        out["encoder"] = count

        def at(p: Part) -> float:
            return p.x_at(count, enc.robot_bits, enc.counts_per_mm)

        out["parts"] = [self._part(p, at(p)) for p in ctx.queue.peek_all()[:MAX_PARTS]]
        board = self.cell.board
        part, phase = board.get(RETRIEVE.PART), board.get(RETRIEVE.PHASE)
        if isinstance(part, Part) and phase in ("pick", "held", "place"):
            # "pick": still on the belt, the robot tracking it; "held"/"place": gripped
            out["picking"] = {**self._part(part, at(part)), "phase": phase}
        return out
