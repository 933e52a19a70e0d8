"""Scoring a taught recipe on held-out labelled images: a confusion table and each class's
precision, recall and F1, false positives counted.

A detection is a label's part when its centroid lies in the label's box (each label takes
at most one, the nearest its box's centre); a detection in no box is a false positive (row
``(none)``), a label with no detection a miss (column ``(missed)``). Labels cut by the
image's edge are neither: the locator leaves such parts for the next frame, and a
detection in their box is not counted. ``plain_baseline`` is the pipeline a person would
write first with OpenCV (Otsu, contours, nearest class by area), scored the same way.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from feeder_bt.tuning.labels import Sample

NONE = "(none)"
MISSED = "(missed)"

Found = list[tuple[str, float, float]]          # (class, u_px, v_px) per detection


@dataclass
class Scores:
    """Counts of (true class, found class) pairs, and what follows from them."""

    classes: list[str]
    pairs: dict[tuple[str, str], int] = field(default_factory=dict)

    def add(self, truth: str, found: str) -> None:
        self.pairs[(truth, found)] = self.pairs.get((truth, found), 0) + 1

    def _count(self, truth: str | None = None, found: str | None = None) -> int:
        return sum(n for (t, f), n in self.pairs.items()
                   if (truth is None or t == truth) and (found is None or f == found))

    def prf(self, cls: str) -> tuple[float, float, float]:
        tp = self.pairs.get((cls, cls), 0)
        fp = self._count(found=cls) - tp
        fn = self._count(truth=cls) - tp
        p = tp / (tp + fp) if tp + fp else 0.0
        r = tp / (tp + fn) if tp + fn else 0.0
        return p, r, (2 * p * r / (p + r) if p + r else 0.0)

    @property
    def f1(self) -> float:
        """Micro-averaged F1 over the classes: every part and every false find counts once."""
        tp = sum(self.pairs.get((c, c), 0) for c in self.classes)
        found = sum(n for (_, f), n in self.pairs.items() if f != MISSED)
        truth = sum(n for (t, _), n in self.pairs.items() if t != NONE)
        p = tp / found if found else 0.0
        r = tp / truth if truth else 0.0
        return 2 * p * r / (p + r) if p + r else 0.0

    def table(self) -> list[str]:
        """The confusion table (rows: labelled, columns: found) and per-class scores."""
        cols = [*self.classes, MISSED]
        rows = [*self.classes, NONE]
        w = max(len(c) for c in [*cols, *rows, "labelled \\ found"]) + 2
        out = ["labelled \\ found".ljust(w) + "".join(c.rjust(w) for c in cols)]
        for r in rows:
            out.append(r.ljust(w) + "".join(
                ("" if (r == NONE and c == MISSED) else str(self.pairs.get((r, c), 0))).rjust(w)
                for c in cols))
        out.append("")
        out.append("class".ljust(w) + "precision".rjust(11) + "recall".rjust(9) + "F1".rjust(7))
        for c in self.classes:
            p, r, f = self.prf(c)
            out.append(c.ljust(w) + f"{p:11.3f}{r:9.3f}{f:7.3f}")
        out.append("all (micro)".ljust(w) + " " * 20 + f"{self.f1:7.3f}")
        return out


def score_finds(samples: list[Sample], finds: Callable[[Sample], Found],
                classes: list[str]) -> Scores:
    """Match each image's detections to its labels (see the module docstring)."""
    sc = Scores(sorted(classes))
    for s in samples:
        h, w = s.image.shape[:2]
        dets = list(finds(s))
        taken = [False] * len(dets)
        for box in s.boxes:
            inside = [i for i, (_, u, v) in enumerate(dets)
                      if not taken[i] and box.contains(u, v)]
            truth = "/".join(box.cls)
            if box.touches_border(w, h):
                for i in inside:
                    taken[i] = True
                continue
            if not inside:
                sc.add(truth, MISSED)
                continue
            cu, cv = box.x + box.w / 2, box.y + box.h / 2
            i = min(inside, key=lambda i: (dets[i][1] - cu) ** 2 + (dets[i][2] - cv) ** 2)
            taken[i] = True
            sc.add(truth, dets[i][0])
        for i, (cls, _, _) in enumerate(dets):
            if not taken[i]:
                sc.add(NONE, cls)
    return sc


def held_out(n: int, fraction: float) -> list[int]:
    """Which of ``n`` images (in name order) to hold out: every k-th, spread evenly, so the
    split is the same on every run and on every machine."""
    return [i for i in range(n) if int((i + 1) * fraction) > int(i * fraction)]


# ---------------------------------------------------------------------------- the baseline


class PlainBaseline:
    """Otsu on the grey image (parts darker or lighter, whichever leaves the image's border
    background), external contours, and each blob named after the class whose mean
    training area is nearest; blobs under half the smallest class's area or touching the
    image's edge are dropped. The areas are in pixels: the same camera throughout."""

    def __init__(self, train: list[Sample]) -> None:
        areas: dict[str, list[float]] = {}
        for s in train:
            for cnt in self._blobs(s):
                m = cv2.moments(cnt)
                if m["m00"] <= 0:
                    continue
                u, v = m["m10"] / m["m00"], m["m01"] / m["m00"]
                hit = [b for b in s.boxes if b.contains(u, v)]
                if len(hit) == 1:
                    areas.setdefault("/".join(hit[0].cls), []).append(cv2.contourArea(cnt))
        self.means = {c: float(np.mean(a)) for c, a in areas.items()}

    @staticmethod
    def _mask(img: np.ndarray) -> np.ndarray:
        grey = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY) if img.ndim == 3 else img
        _, mask = cv2.threshold(grey, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        border = np.concatenate([mask[0], mask[-1], mask[:, 0], mask[:, -1]])
        if np.mean(border) > 127:               # the background came out white: invert
            mask = cv2.bitwise_not(mask)
        return mask

    def _blobs(self, s: Sample) -> list[np.ndarray]:
        cs, _ = cv2.findContours(self._mask(s.image), cv2.RETR_EXTERNAL,
                                 cv2.CHAIN_APPROX_SIMPLE)
        h, w = s.image.shape[:2]
        out = []
        for c in cs:
            x, y, bw, bh = cv2.boundingRect(c)
            if x <= 0 or y <= 0 or x + bw >= w or y + bh >= h:
                continue
            out.append(c)
        return out

    def finds(self, s: Sample) -> Found:
        if not self.means:
            return []
        floor = 0.5 * min(self.means.values())
        out = []
        for c in self._blobs(s):
            a = cv2.contourArea(c)
            m = cv2.moments(c)
            if a < floor or m["m00"] <= 0:
                continue
            cls = min(self.means, key=lambda k: abs(self.means[k] - a))
            out.append((cls, m["m10"] / m["m00"], m["m01"] / m["m00"]))
        return out
