"""Segmentation: a grey frame -> the contours of what the recipe calls foreground.

The image in which parts are bright (``foreground: dark``: the golden image minus the
frame, or the inverted frame; ``light``: the frame minus the golden image, or the frame),
its threshold (``threshold.method``: ``fixed``, ``otsu`` never below ``value``, or
``adaptive`` with OpenCV's ``C``), the morphology, and the contours of the mask, found only
in the rectangles that hold foreground (``Segmenter._contours_holes``). Also where a
contour's edge crosses the threshold between pixels (``Segmenter._bright_source`` and
``kernels.edge_points``), for angles finer than a pixel.

``Segmenter`` holds what one recipe needs for this and nothing of parts or calibration;
``Locator`` (``vision.locator``) is a ``Segmenter`` that also measures and classifies the
blobs. Each frame uses only local state and per-thread scratch images (the golden image is
read, never written), so one segmenter may serve several threads.
"""

from __future__ import annotations

import math
import threading

import cv2
import numpy as np

from feeder_bt.core.model import VisionRecipe
from feeder_bt.vision.chains import Contours, _with_holes
from feeder_bt.vision.jit import kernels


class Segmenter:
    """Thresholds frames against one recipe and finds the contours of the foreground."""

    def __init__(self, recipe: VisionRecipe) -> None:
        self.recipe = recipe
        self._golden: np.ndarray | None = None
        self._light = recipe.foreground == "light"   # parts brighter than the belt
        m = recipe.morphology
        self._open = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (m.open_px, m.open_px))
                      if m.open_px > 1 else None)
        self._close = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (m.close_px, m.close_px))
                       if m.close_px > 1 else None)
        # Opening then closing reads the thresholded mask up to this far (px) from a pixel:
        # regions of the image this far clear of foreground are left empty by them.
        reach = sum(2 * (k.shape[0] // 2) for k in (self._open, self._close) if k is not None)
        self._margin = reach + 1
        # kernels symmetric about their centre: an image's mirror stays its mirror
        self._mirror = all(k.shape[0] % 2 == 1 and k.shape[1] % 2 == 1
                           and (k == k[::-1]).all() and (k == k[:, ::-1]).all()
                           for k in (self._open, self._close) if k is not None)
        # the kernels' points (dy, dx from the anchor) for ``kernels.packed_morph``
        self._open_pts, self._close_pts = (_points(k) for k in (self._open, self._close))
        self._golden_small: np.ndarray | None = None     # its subsample (``subsample``)
        self._scratch = threading.local()         # per-thread frame-sized images, reused

    # -------------------------------------------------------------- images

    def set_golden(self, image: np.ndarray) -> None:
        """Remember the cleared belt; later frames are compared against it."""
        self._golden = to_grey(image).copy()     # a copy is C-ordered, as the kernels read it
        self._golden_small = subsample(self._golden).copy()

    def _against_golden(self, img: np.ndarray) -> tuple[bool, float] | None:
        """Where the mask is one comparison of the frame with the golden image (a fixed or
        Otsu level, ``kernels.golden_threshold``): (Otsu's or not, the level or the least Otsu
        may give); else None (no golden image, another method, a fixed level outside
        0-254: the difference image is made and thresholded)."""
        th = self.recipe.threshold
        golden = self._golden
        if not self.recipe.golden_image or golden is None or golden.shape != img.shape:
            return None
        if th.method == "fixed" and 0 <= math.floor(th.value) < 255:
            return False, float(th.value)
        if th.method == "otsu":
            return True, float(th.value)
        return None

    def foreground(self, image: np.ndarray) -> np.ndarray:
        """Binary mask (0/255) of what the recipe considers parts."""
        return self._morph(self._threshold(to_grey(image))[0].copy())

    def _buffer(self, name: str, shape: tuple[int, ...]) -> np.ndarray:
        """A frame-sized uint8 scratch image of this thread's, reused from frame to frame.

        A fresh frame-sized array each frame costs more than the operation writing it when
        the allocator hands the pages back and faulted them in again (2-3x on the bench).
        Its rows are padded with zero columns to whole 8-byte words (``_words``).
        """
        bufs: dict[str, np.ndarray] | None = getattr(self._scratch, "bufs", None)
        if bufs is None:
            bufs = self._scratch.bufs = {}
        buf = bufs.get(name)
        if buf is None or buf.shape != shape:
            h, w = shape
            padded = np.zeros((h, -(-w // 8) * 8), dtype=np.uint8)
            buf = bufs[name] = padded[:, :w]
            words = getattr(self._scratch, "words", None)
            if words is None:
                words = self._scratch.words = {}
            words[id(buf)] = (buf, padded.view(np.uint64))
        return buf

    def _words(self, mask: np.ndarray) -> np.ndarray:
        """The mask as 8 pixels a word (``kernels.foreground_rois``): a scratch image's own
        padded rows, else a padded copy."""
        got = getattr(self._scratch, "words", {}).get(id(mask))
        if got is not None and got[0] is mask:
            return got[1]
        h, w = mask.shape
        padded = np.zeros((h, -(-w // 8) * 8), dtype=np.uint8)
        padded[:, :w] = mask
        return padded.view(np.uint64)

    def _diff(self, img: np.ndarray, dst: np.ndarray | None = None) -> np.ndarray:
        """The image in which parts are bright: for dark parts the golden image minus the
        frame (or the inverted frame), for light parts the frame minus the golden image
        (or the frame itself)."""
        golden = self._golden
        if self.recipe.golden_image and golden is not None:
            if self._light:
                return cv2.subtract(img, golden, dst=dst)
            return cv2.subtract(golden, img, dst=dst)
        if self._light:
            return img
        return cv2.bitwise_not(img, dst=dst)

    def _threshold(self, img: np.ndarray) -> tuple[np.ndarray, np.ndarray | None, float | None]:
        """The thresholded mask (before morphology), the difference image (None if it was
        not needed) and the level (None: adaptive). The images are this thread's scratch
        images, valid until its next frame."""
        th = self.recipe.threshold
        mask = self._buffer("mask", img.shape)
        golden = self._against_golden(img)
        if golden is not None:
            # the frame against the golden image, no difference image (the faces read the
            # grey from the frame and the golden image where they need it)
            level = kernels().golden_threshold(
                np.ascontiguousarray(img), self._golden, self._golden_small,
                _sample_step(*img.shape), *golden, self._light,
                self._words(mask).view(np.uint8))
            return mask, None, level
        diff = self._diff(img, self._buffer("diff", img.shape))
        if th.method == "fixed":
            level: float | None = float(th.value)
            cv2.threshold(diff, th.value, 255, cv2.THRESH_BINARY, dst=mask)
        elif th.method == "otsu":
            level = max(otsu_level(diff), float(th.value))
            cv2.threshold(diff, level, 255, cv2.THRESH_BINARY, dst=mask)
        elif th.method == "adaptive":
            level = None
            block = max(3, int(th.block_px) | 1)
            # OpenCV's meaning of C: foreground where the part-bright image is above its
            # local mean minus c (so c < 0: that far above the mean)
            cv2.adaptiveThreshold(diff, 255, cv2.ADAPTIVE_THRESH_MEAN_C,
                                  cv2.THRESH_BINARY, block, th.c, dst=mask)
        else:
            raise ValueError(f"unknown threshold method {th.method!r}")
        return mask, diff, level

    def _morph(self, mask: np.ndarray) -> np.ndarray:
        if self._open is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, self._open)
        if self._close is not None:
            mask = cv2.morphologyEx(mask, cv2.MORPH_CLOSE, self._close)
        return mask

    def _rois(self, mask: np.ndarray) -> np.ndarray:
        """Rectangles (v0, v1, u0, u1) that hold all the foreground, each with a margin of
        empty pixels wider than the morphology reaches (or the image's edge).

        Cut where more than ``2 * margin`` empty rows part the foreground, then each
        piece's columns likewise, and so on, each piece trimmed to its foreground (an
        XY-cut): most of a frame is empty belt. Compiled, reading the mask 8 pixels a word
        (``kernels.foreground_rois``).
        """
        h, w = mask.shape
        return kernels().foreground_rois(self._words(mask), h, w, self._margin)

    def _contours(self, mask: np.ndarray, full: bool) -> list[np.ndarray]:
        """External contours of the opened and closed ``mask`` (``_contours_holes``)."""
        return self._contours_holes(mask, full, holes=False)[0]

    def _segment(self, img: np.ndarray, full: bool, holes: bool
                 ) -> tuple[list[np.ndarray], list[list[np.ndarray]] | None,
                            np.ndarray | None, float | None]:
        """A grey frame's contours and holes (``_contours_holes``), its difference image
        and level (``_threshold``). Against a golden image with symmetric kernels (every
        shipped recipe), Otsu's level, the mask and its packed morphology are one compiled
        call (``kernels.golden_morph``)."""
        golden = self._against_golden(img) if self._mirror else None
        if golden is None:
            mask, diff, level = self._threshold(img)
            return (*self._contours_holes(mask, full, holes), diff, level)
        mask = self._buffer("mask", img.shape)
        level, *morphed = kernels().golden_morph(
            np.ascontiguousarray(img), self._golden, self._golden_small,
            _sample_step(*img.shape), *golden, self._light, self._words(mask).view(np.uint8),
            self._margin, *self._open_pts, *self._close_pts)
        return (*self._contours_holes(mask, full, holes, tuple(morphed)), None, level)

    def _contours_holes(self, mask: np.ndarray, full: bool, holes: bool,
                        morphed: tuple | None = None
                        ) -> tuple[list[np.ndarray], list[list[np.ndarray]] | None]:
        """External contours of the opened and closed ``mask`` (with symmetric kernels,
        ``morphed``: ``kernels.packed_morph``'s result for it, if already made), in
        ``findContours``' order
        (as on the whole frame: by first point, last found first), and with ``holes`` each
        one's hole contours (``RETR_CCOMP``; else None).

        The morphology and the contour search run only on ``_rois``: inside each, every
        pixel comes out as on the whole frame, outside them nothing does. The rectangles
        are laid side by side in one small image (their margins keep them apart, as on the
        frame), so a frame costs one morphology and one contour search however many
        blobs it has. Where a rectangle meets the image's edge, which the morphology reads
        as "nothing there to constrain", it gets a mirror image of itself as wide as the
        margin: with a symmetric kernel each operation keeps the mirror a mirror, so up to
        the edge every pixel comes out as on the frame. The mirrors are cleared before the
        contour search (whose own border is empty, as at the image's edge). With symmetric
        kernels (or none) the rectangles, their packing, the opening, the closing and the
        clearing are one compiled call working a bit a pixel (``kernels.packed_morph``);
        with others, OpenCV's ``morphologyEx`` on the packed bytes.
        """
        h, w = mask.shape
        k = kernels()
        mode = cv2.RETR_CCOMP if holes else cv2.RETR_EXTERNAL
        chain = cv2.CHAIN_APPROX_NONE if full else cv2.CHAIN_APPROX_SIMPLE
        own: list[tuple[np.ndarray, list[np.ndarray]]] = []    # found in the frame's place
        if not self._mirror:
            # an asymmetric kernel: rectangles at the image's edge get their own search
            rois = self._rois(mask)
            edge = (rois[:, 0] == 0) | (rois[:, 1] == h) | (rois[:, 2] == 0) | (rois[:, 3] == w)
            for v0, v1, u0, u1 in rois[edge].tolist():
                cs, hier = cv2.findContours(self._morph(mask[v0:v1, u0:u1]), mode, chain,
                                            offset=(u0, v0))
                own += _with_holes(cs, hier, holes)
            rois = np.ascontiguousarray(rois[~edge])
            # none of them meets the image's edge: no mirrors
            packed, geo = k.pack_rois(mask, rois, 0) if len(rois) else (None, _NO_GEO)
            if len(rois):
                packed = self._morph(packed)
        else:
            # a rectangle at the image's edge has no empty margin there: it gets a mirror
            # (for the morphology), which also keeps it one pixel clear of its neighbours;
            # packed, opened, closed and the mirrors cleared a bit a pixel in one call
            # (without morphology the margin is 1: the packing alone)
            rois, words, geo, width = morphed if morphed is not None else k.packed_morph(
                self._words(mask), h, w, self._margin, *self._open_pts, *self._close_pts)
            packed = words.view(np.uint8)[:, :width]
        found: list[tuple[np.ndarray, list[np.ndarray]]] = []
        if len(rois):
            cs, hier = cv2.findContours(packed, mode, chain)
            found = _with_holes(cs, hier, holes)
        n_packed = len(found)
        found += own
        if not found:
            return Contours(_NO_POINTS, _NO_LENS), ([] if holes else None)
        outer = [c for c, _ in found]
        pts = np.concatenate(outer).reshape(-1, 2)
        lens = np.fromiter(map(len, outer), np.int64, len(outer))
        # back to the frame; the whole frame's findContours lists contours by first
        # point, last found first
        pts, lens, order, moved = k.place_contours(pts, lens, n_packed, geo, w)
        contours = Contours(pts, lens)
        if not holes:
            return contours, None
        out_holes = []
        for i, (du, dv) in zip(order.tolist(), moved[order].tolist(), strict=True):
            hs = found[i][1]
            for hole in hs:                   # a blob's holes lie in its rectangle
                hole += np.array([du, dv], dtype=np.int32)
            out_holes.append(hs)
        return contours, out_holes

    def _bright_source(self, img: np.ndarray, diff: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray, int]:
        """How ``kernels.edge_points`` reads the image in which parts are bright (``_diff``)
        at a pixel: (the frame's difference image if it was made, else the frame; the
        golden image or a placeholder; ``kernels``' mode), the images flat.

        Where the outline crosses the level between pixels, for angles finer than a pixel
        (``Locator._faces``): a binary contour moves in whole pixels, which limits the angle
        of a near-axis edge to about 1°; the grey levels say where the edge is. Between
        each boundary pixel given (the vertices of each blob's pixel hull) and each of its
        4-neighbours outside the level, the difference image (interpolated linearly, as a
        bilinear image is along that line) crosses the level at one point. Only the blob's
        own boundary is read, so a neighbour in its box is no trouble. Without a level
        (adaptive threshold), or if a contour has too few such points, the contours'
        pixels are used.
        """
        k = kernels()
        if diff is not None:
            return diff.reshape(-1), _NO_GOLDEN, k.DIFF
        flat = np.ascontiguousarray(img).reshape(-1)
        golden = self._golden
        if self.recipe.golden_image and golden is not None:
            return flat, golden.reshape(-1), k.GOLDEN_LIGHT if self._light else k.GOLDEN_DARK
        return flat, _NO_GOLDEN, k.PLAIN_LIGHT if self._light else k.PLAIN_DARK


def _points(kernel: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """A structuring element's points as (dy, dx) from its anchor, its centre (OpenCV's
    default); none for no kernel."""
    if kernel is None:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dy, dx = np.nonzero(kernel)
    return ((dy - kernel.shape[0] // 2).astype(np.int64),
            (dx - kernel.shape[1] // 2).astype(np.int64))


_NO_GOLDEN = np.zeros(1, np.uint8)
_NO_POINTS = np.zeros((0, 2), np.int32)
_NO_LENS = np.zeros(0, np.int64)
_NO_GEO = np.zeros((0, 9), np.int64)


OTSU_STEP = 4       # Otsu's level from every 4th pixel of every 4th row


def _sample_step(h: int, w: int) -> int:
    """The step of ``subsample`` for an h x w image: ``OTSU_STEP``, or 1 (whole) if small."""
    return 1 if h < 4 * OTSU_STEP or w < 4 * OTSU_STEP else OTSU_STEP


def subsample(img: np.ndarray) -> np.ndarray:
    """Every ``OTSU_STEP``-th pixel of every ``OTSU_STEP``-th row (a view; a small image
    whole), where Otsu's level is read."""
    step = _sample_step(*img.shape[:2])
    return img if step == 1 else img[::step, ::step]


def otsu_level(img: np.ndarray, golden_small: np.ndarray | None = None,
               mode: str = "plain") -> float:
    """Otsu's level of the difference image's regular subsample (``subsample``): of ``img``
    itself (``plain``), of ``img`` minus the golden image (``minus_golden``) or of the golden
    image minus ``img`` (``golden_minus``), ``golden_small`` being the golden image's
    subsample. As ``cv2.threshold``'s ``THRESH_OTSU`` gives it on that sample.

    The level is a property of the histogram's two modes, belt and parts, which a 1/16
    sample of a frame shows as well as the whole frame (the parts' smallest blobs still
    cover tens of samples); the whole frame's histogram was a fifth of the locator's time
    on a frame of squares (benchmarks/vision_bench.py). The mask is still cut from every
    pixel, at this level. Compiled (``kernels.otsu_level``): the sample read in place,
    never copied out of the frame.
    """
    k = kernels()
    h, w = img.shape[:2]
    step = _sample_step(h, w)
    if golden_small is None:
        mode, golden_small = "plain", _sample_shape(h, w, step)
    return k.otsu_level(np.ascontiguousarray(img), golden_small, step,
                        {"plain": k.PLAIN, "minus_golden": k.MINUS_GOLDEN,
                         "golden_minus": k.GOLDEN_MINUS}[mode])


def _sample_shape(h: int, w: int, step: int) -> np.ndarray:
    """A placeholder golden sample (C order, as the golden image's): only its shape, the
    sample's, is read."""
    return np.zeros((-(-h // step), -(-w // step)), np.uint8)


def to_grey(image: np.ndarray) -> np.ndarray:
    """The image as uint8 grey (a BGR colour image is converted): what the recipe reads."""
    if image.ndim == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if image.dtype != np.uint8:
        raise TypeError("the locator takes uint8 grey images")
    return image
