"""No silent zero: notice when frames show blobs but the recipe finds no part in them.

A recipe whose class ranges were measured at another threshold, on another camera or for
another part finds blobs on every frame and classes none of them; a size in the wrong unit
makes every blob "too small"; a part too big for the window always "touches border". The
cell runs, locates nothing and would stop at the end with nothing said. ``RecipeWatch``
sees every frame's result; when frames have shown blobs, for any reason none of them a
part (no class, too small, touching the border), and no part at all, for ``after_s`` of
the run's time, it emits a ``vision_no_match`` event (the live view and the event log show
it; again every ``repeat_s`` while it lasts) naming the commonest reason (for "no class",
the class nearest the blobs and the feature most often out of range), and keeps a summary
for the report. A frame with a part in it ends the spell (``vision_matches`` if an alarm
was raised). Empty frames are not evidence either way. A part that touches the border in
one frame is seen whole in the next (``locate.frame_spacing_mm`` is checked for it), so
a normal run never has a spell of border blobs this long.
"""

from __future__ import annotations

import re
from collections import Counter
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from feeder_bt.vision.locator import LocateResult

AFTER_S = 30.0              # blobs and no match for this long: say so
REPEAT_S = 30.0             # and again this often while it lasts

# "no class; nearest lens/flat: area_mm2 4118 not in [1800, 2300]"
_REASON = re.compile(r"^no class; nearest (?P<cls>\S+): (?P<feature>\S+)")
_VALUE = re.compile(r": (?P<feature>\S+) (?P<v>[-+\d.eE]+) not in \[(?P<lo>[^,]+), (?P<hi>[^\]]+)\]")
# a parenthesis holding a figure: "(overlap 0.83)", "(overlap 0.90 vs 0.88: ...)"
_FIGURES = re.compile(r"\s*\([^()]*\d[^()]*\)")
LINE_CHARS = 200            # a hint or a summary line: at most this long
TOUCHING = 1.6              # a blob this many times a class's largest area: parts touching


class RecipeWatch:
    """Counts frames whose blobs fit no class; raises the alarm described above."""

    def __init__(self, after_s: float = AFTER_S, repeat_s: float = REPEAT_S) -> None:
        self.after_s, self.repeat_s = after_s, repeat_s
        self.since: float | None = None       # start of the present spell of no matches
        self.last_alarm: float | None = None
        self.alarms = 0
        self.frames_no_match = 0              # frames with unmatched blobs and no part
        self.longest_s = 0.0
        self.nearest: Counter[tuple[str, str]] = Counter()   # (class, feature) over the run
        self.examples: dict[tuple[str, str], str] = {}        # the latest reason of each

    def feed(self, t: float, result: LocateResult, stats: Any) -> None:
        """One frame's result at time ``t``; events go to ``stats.emit``."""
        if result.parts:
            if self.since is not None and self.last_alarm is not None:
                stats.emit(t, "vision_matches", after_s=round(t - self.since, 1))
            self.since = self.last_alarm = None
            return
        unmatched = [d.reason for d in result.rejected if d.reason]
        if not unmatched:
            return
        self.frames_no_match += 1
        spell = Counter()
        for reason in unmatched:
            key = _key(reason)
            spell[key] += 1
            self.nearest[key] += 1
            self.examples[key] = reason
        if self.since is None:
            self.since = t
        lasted = t - self.since
        self.longest_s = max(self.longest_s, lasted)
        if lasted >= self.after_s and (self.last_alarm is None
                                       or t - self.last_alarm >= self.repeat_s):
            self.last_alarm = t
            self.alarms += 1
            (cls, feature), _ = spell.most_common(1)[0]
            example = self.examples[(cls, feature)]
            stats.emit(t, "vision_no_match", seconds=round(lasted, 1), nearest=cls,
                       feature=feature, example=example,
                       hint=_hint(len(unmatched), cls, feature, example))

    def restarted(self) -> None:
        """The job restarted (after an e-stop, a fault): a spell of no matches does not
        span the stop; the run's counts go on."""
        self.since = self.last_alarm = None

    def summary(self) -> dict[str, Any]:
        """For the run report: how long the recipe matched nothing, and why."""
        out: dict[str, Any] = {"alarms": self.alarms, "frames_no_match": self.frames_no_match,
                               "longest_s": round(self.longest_s, 1)}
        if self.nearest:
            (cls, feature), n = self.nearest.most_common(1)[0]
            reasons: Counter[str] = Counter()
            for k, v in self.nearest.items():     # by kind: no blob's own figures
                reasons[_reason_name(k)] += v
            out.update(nearest=cls, feature=feature, blobs=n,
                       example=self.examples[(cls, feature)],   # the commonest reason's
                       reasons=dict(reasons.most_common()))
        return out


def _key(reason: str) -> tuple[str, str]:
    """(class, feature) of a "no class" reason; ("-", its kind) of the others: the
    reason without the blob's own figures, so that alike reasons group."""
    m = _REASON.match(reason)
    return (m["cls"], m["feature"]) if m else ("-", reason_kind(reason))


def reason_kind(reason: str) -> str:
    """A reject reason without its figures ("no class (outline does not match (overlap
    0.83))" -> "no class (outline does not match)"); a "no class; nearest" reason keeps
    its class and feature only."""
    m = _REASON.match(reason)
    if m:
        return f"no class; nearest {m['cls']}: {m['feature']}"
    prev = None
    while prev != reason:
        prev, reason = reason, _FIGURES.sub("", reason)
    return reason


def touching(reason: str) -> float | None:
    """How many times its nearest class's largest area a blob rejected on ``area_mm2``
    measures, when that is ``TOUCHING`` or more (parts lying against each other); else
    None."""
    m = _VALUE.search(reason)
    if m is None or m["feature"] != "area_mm2":
        return None
    try:
        v, hi = float(m["v"]), float(m["hi"])
    except ValueError:
        return None
    return v / hi if hi > 0 and v >= TOUCHING * hi else None


def short(text: str, limit: int = LINE_CHARS) -> str:
    """``text`` cut to ``limit`` characters (an ellipsis at the cut)."""
    return text if len(text) <= limit else text[:limit - 1].rstrip() + "…"


def _reason_name(key: tuple[str, str]) -> str:
    return key[1] if key[0] == "-" else f"no class ({key[0]} {key[1]})"


def _hint(n: int, cls: str, feature: str, example: str = "") -> str:
    """What to look at, by the commonest kind of reason of the spell: one short line."""
    if feature == "too small":
        text = (f"{n} blob(s) in the last frame, all under vision.min_area_mm2: a part's "
                f"size in the wrong unit, or the camera's mm_per_px? (`feeder locate`)")
    elif feature == "touches border":
        text = (f"{n} blob(s) in the last frame, all cut by the image border: parts too "
                f"big for the camera window, or frames too far apart?")
    elif cls == "-" and "orientation ambiguous" in feature:
        text = (f"{n} blob(s) in the last frame rejected: {feature}: give the part's "
                f"symmetry (or mirror_symmetric) if it looks alike turned (`feeder check`)")
    elif cls == "-" and "outline does not match" in feature:
        text = (f"{n} blob(s) in the last frame rejected: {feature}: another pose's "
                f"outline, or vision.outline_match.min_iou too high for the camera? "
                f"(`feeder locate`)")
    elif cls == "-":
        text = f"{n} blob(s) in the last frame rejected: {feature}"
    elif (k := touching(example)) is not None:
        text = (f"{n} blob(s) in the last frame fit no class; blobs of {k:.1f}x {cls}'s "
                f"area: parts touching? spread them (a slower incline) or set "
                f"vision.split_touching: true")
    else:
        text = (f"{n} blob(s) in the last frame fit no class; check the ranges of {cls} "
                f"({feature}) with `feeder locate`")
    return short(text)


def reasons_line(reasons: dict[str, int], limit: int = LINE_CHARS) -> str:
    """Blobs per kind of reason, commonest first, as one line of at most ``limit``
    characters (the kinds that do not fit counted as "N more")."""
    items = sorted(reasons.items(), key=lambda kv: -kv[1])
    parts: list[str] = []
    for i, (k, v) in enumerate(items):
        left = len(items) - i                       # this one and those after it
        part = f"{k} {v}"
        more = f", {left - 1} more" if left > 1 else ""
        if len(", ".join([*parts, part])) + len(more) > limit:
            if parts:
                return ", ".join(parts) + f", {left} more"
            return short(part, limit - len(more)) + more
        parts.append(part)
    return ", ".join(parts)


def recipe_watch(extras: dict[str, Any]) -> RecipeWatch:
    """The cell's one watch, kept in ``Ctx.extras`` (made on first use)."""
    watch = extras.get("recipe_watch")
    if watch is None:
        watch = extras["recipe_watch"] = RecipeWatch()
    return watch
