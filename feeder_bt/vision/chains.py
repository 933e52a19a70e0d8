"""Pixel contours: their full chains, lengths, and the runs the locator packs by.

Helpers of ``feeder_bt.vision`` (segmentation, blobs) that need no recipe.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from feeder_bt.vision.jit import kernels

WINDOW = 5                     # points in the moving average of the smoothed perimeter


class Contours(Sequence):
    """Contours in the frame, their points one after another (``pts``: (n, 2) int32;
    ``lens``: each one's count): ``blobs.find_blobs`` measures them as they are; each as an
    (n, 1, 2) array, as ``findContours`` gives them, is a view made only when asked for
    (drawing, the rarer features)."""

    def __init__(self, pts: np.ndarray, lens: np.ndarray) -> None:
        self.pts, self.lens = pts, lens
        self._starts: list[int] | None = None

    def contour(self, i: int) -> np.ndarray:
        """Contour ``i``: a (n, 1, 2) view of the points."""
        if self._starts is None:
            self._starts = (np.cumsum(self.lens) - self.lens).tolist()
        a = self._starts[i]
        return self.pts[a:a + int(self.lens[i])].reshape(-1, 1, 2)

    def __len__(self) -> int:
        return len(self.lens)

    def __getitem__(self, i):  # an index or a slice, as a list's
        if isinstance(i, slice):
            return [self.contour(j) for j in range(*i.indices(len(self)))]
        if i < 0:
            i += len(self)
        if not 0 <= i < len(self):
            raise IndexError("contour index out of range")
        return self.contour(i)


def _full_chain(contour: np.ndarray) -> np.ndarray:
    """The ``CHAIN_APPROX_NONE`` contour of a ``CHAIN_APPROX_SIMPLE`` one: each segment
    between two corners is a straight horizontal, vertical or diagonal run of pixels."""
    pts = contour.reshape(-1, 2)
    step = np.roll(pts, -1, axis=0) - pts
    n = np.abs(step).max(axis=1)
    if len(pts) == 1 or not n.all():
        return contour
    at = np.repeat(np.arange(len(pts)), n)
    k = np.arange(len(at)) - np.repeat(np.cumsum(n) - n, n)       # steps into the segment
    return (pts[at] + k[:, None] * (step // n[:, None])[at]).astype(np.int32).reshape(-1, 1, 2)


def _with_holes(contours: tuple[np.ndarray, ...], hierarchy: np.ndarray | None, holes: bool
                ) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """``findContours``' outer contours, each with its holes' (``RETR_CCOMP``'s two levels:
    an outer contour's children are its holes; without ``holes``, none)."""
    if not holes or hierarchy is None:
        return [(c, []) for c in contours]
    hier = hierarchy.reshape(-1, 4)
    kids: dict[int, list[np.ndarray]] = {}
    for i, parent in enumerate(hier[:, 3].tolist()):
        if parent >= 0:
            kids.setdefault(parent, []).append(contours[i])
    return [(c, kids.get(i, [])) for i, c in enumerate(contours) if hier[i, 3] < 0]


def _chain_steps(contours: list[np.ndarray]) -> list[int]:
    """Points of the full 8-connected chain (``CHAIN_APPROX_NONE``) of closed contours
    given by their ``CHAIN_APPROX_SIMPLE`` vertices: each segment between two vertices is
    a straight horizontal, vertical or diagonal run of max(|du|, |dv|) steps. All the
    contours in one set of array operations."""
    sizes = [len(c) for c in contours]
    pts = np.concatenate(contours).reshape(-1, 2)
    ends = np.cumsum(sizes)
    nxt = np.empty_like(pts)
    nxt[:-1] = pts[1:]
    nxt[ends - 1] = pts[ends - sizes]             # each contour closes on its first point
    steps = np.abs(nxt - pts).max(axis=1)
    out = np.add.reduceat(steps, ends - sizes).tolist()
    return [n if size > 1 else 1 for n, size in zip(out, sizes, strict=True)]


def _boundary_steps(contours: list[np.ndarray], full: bool) -> list[int]:
    """Boundary pixels of each closed contour (for Pick's theorem): its points if ``full``
    (``CHAIN_APPROX_NONE``), else counted from its corners (``_chain_steps``)."""
    if not contours:
        return []
    return [len(c) for c in contours] if full else _chain_steps(contours)


def _smooth_length(contour: np.ndarray, window: int = WINDOW) -> float:
    """Length of a closed pixel contour after a circular moving average of its points.

    The averaged points' steps are ``(p[i + window] - p[i]) / window`` (neighbouring windows
    differ by one point in, one out), so the length is the sum of the distances between
    points ``window`` apart: the perimeter of the polygon that visits the contour
    ``window`` points at a time (one closed tour when n and ``window`` are coprime, else
    ``window`` of them), summed as ``cv2.arcLength`` sums (``kernels.smooth_length``; the
    locator measures a frame's blobs in one call, ``kernels.blob_stats``). A contour
    shorter than two windows keeps its plain length.
    """
    uv = np.ascontiguousarray(contour.reshape(-1, 2), dtype=np.int32)
    return float(kernels().smooth_length(uv, 0, len(uv), window))
