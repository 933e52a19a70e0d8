"""The Galil DMC conveyor controller: ASCII protocol over pyserial (serial port or
``socket://``), the conveyors and digital I/O on it.

``protocol`` is pure (splitter, errors, formatting, download preparation); ``driver`` owns
the link and the device worker; ``conveyor`` has the HAL devices.
"""

from __future__ import annotations

from pathlib import Path

from feeder_bt.core.clock import Clock
from feeder_bt.core.model import CellSpec
from feeder_bt.hal.galil.conveyor import GalilConveyor, GalilIO
from feeder_bt.hal.galil.driver import PROGRAMS_DIR, GalilController
from feeder_bt.hal.galil.protocol import DownloadError, GalilError


def make_galil(cell: CellSpec, clock: Clock, programs_dir: Path | str = PROGRAMS_DIR
               ) -> tuple[GalilController, dict[str, GalilConveyor], GalilIO]:
    """The controller of ``cell.galil``, a conveyor per ``cell.galil.axes`` entry and the
    controller's I/O under the cell's signal names. Connects in the background
    (``controller.ready``)."""
    ctl = GalilController(cell.galil, clock, programs_dir,
                          counts_per_mm=cell.encoder.counts_per_mm)
    conveyors = {}
    for name, axis in cell.galil.axes.items():
        spec = cell.conveyors.get(name)
        conveyors[name] = GalilConveyor(
            ctl, name, axis, cell.encoder.counts_per_mm,
            max_mm_s=spec.max_mm_s if spec else 400.0,
            accel_mm_s2=spec.accel_mm_s2 if spec else 1500.0, cell_file=cell.path)
    return ctl, conveyors, GalilIO(ctl, cell.io)


__all__ = ["DownloadError", "GalilController", "GalilConveyor", "GalilError", "GalilIO",
           "make_galil"]
