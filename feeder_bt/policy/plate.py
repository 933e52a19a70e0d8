"""Smart feeding: the next plate action from what the last frame showed.

The thesis's adjust sub-system retunes the presentation from what the locator saw; for a
vibrating plate that means choosing the next action rather than a speed. The view is the
recipe's result only (blobs found, classed or rejected, and where) — never the
simulator's truth. A ``fixed`` policy (dispense, feed forward and flip on every Nth look
that found nothing new, else flip) is the comparison.
"""

from __future__ import annotations

from dataclasses import dataclass

from feeder_bt.core.plate_model import PlatePolicy, PlateSpec

Action = tuple[str, int]        # (PLATE_ACTIONS name, repetitions)


@dataclass(frozen=True)
class PlateView:
    """What one frame of the plate showed."""

    pickable: int           # blobs classed as a pickable pose
    unpickable: int         # blobs classed as a pose the robot cannot take (on edge, face down)
    rejected: int           # blobs no class took (touching parts, clumps)
    centre: float | None    # the blobs' area-weighted centre along the feed, 0 rear .. 1 front
    parts: float = 0.0      # parts on the plate, estimated: blob area over one part's area

    @property
    def blobs(self) -> int:
        return self.pickable + self.unpickable + self.rejected


def part_area_mm2(recipe: object) -> float:
    """One part's area as the recipe knows it: the middle of the first pickable class's
    area range (a clump of touching parts is one blob: its area counts its parts)."""
    for c in getattr(recipe, "classes", []):
        rng = getattr(c, "area_mm2", None)
        if c.pickable and rng:
            return (float(rng[0]) + float(rng[1])) / 2.0
    return 1000.0


def view_of(result: object, plate: PlateSpec, part_area: float) -> PlateView:
    """Summarise a recipe result (``parts`` and ``rejected`` detections, plate mm)."""
    parts = list(getattr(result, "parts", []) or [])
    rejected = list(getattr(result, "rejected", []) or [])
    blobs = parts + rejected
    areas = [max(float(d.features.get("area_mm2", part_area)), 1.0) for d in blobs]
    centre = None
    if blobs:
        cx = sum(a * d.x_mm for a, d in zip(areas, blobs, strict=True)) / sum(areas)
        centre = (cx - plate.origin_mm[0]) / plate.size_mm[0]
    pickable = sum(1 for d in parts if d.pickable)
    return PlateView(pickable, len(parts) - pickable, len(rejected), centre,
                     sum(areas) / part_area)


def next_actions(view: PlateView, policy: PlatePolicy,
                 empty_look: int = 1) -> tuple[list[Action], str]:
    """The actions to run before the next look, and why (one line for the event log).
    ``empty_look`` counts the looks judged so far, this one included (1, 2, ...): the fixed
    cycle's full cycle comes on the first and every ``fixed_every``-th after it."""
    if policy.policy == "fixed":
        if (empty_look - 1) % policy.fixed_every == 0:
            return ([("dispense", policy.dispense_reps), ("feed_forward", policy.feed_reps),
                     ("flip", policy.flip_reps)], "fixed cycle")
        return [("flip", policy.flip_reps)], f"fixed cycle: flip ({policy.fixed_every})"
    n = view.parts
    if n > policy.crowded_parts:
        return ([("purge", policy.purge_reps)],
                f"crowded: about {n:.0f} parts > {policy.crowded_parts}")
    if n < policy.min_parts:
        return ([("dispense", policy.dispense_reps)],
                f"too few: about {n:.0f} parts < {policy.min_parts}")
    bad = (view.unpickable + view.rejected) / max(view.blobs, 1)
    if view.centre is not None and abs(view.centre - 0.5) > policy.cluster_fraction:
        direction = "feed_forward" if view.centre < 0.5 else "feed_backward"
        return ([(direction, policy.feed_reps)],
                f"clustered at {'the rear' if view.centre < 0.5 else 'the front'} "
                f"({view.centre:.2f} of the length)")
    if bad >= policy.flip_fraction:
        return [("flip", policy.flip_reps)], f"{bad:.0%} not pickable: flip"
    # spread out but nothing new to pick: touching or turned parts, shake them apart
    return [("flip", policy.flip_reps)], "nothing new to pick: flip to separate"
