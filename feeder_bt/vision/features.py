"""Blob features a recipe's classes may range over (mm and mm² through the calibration)."""

FEATURES: dict[str, str] = {
    "area_mm2": "blob area in mm² inside its outer contour (holes included)",
    "holes": "number of holes (of at least min_hole_mm2)",
    "hole_area_mm2": "total area of those holes in mm²",
    "perimeter_mm": "contour length in mm",
    "circularity": "4·π·area / perimeter², 1 for a disc",
    "aspect": "long side / short side of the minimum-area rectangle",
    "rectangularity": "area / area of the minimum-area rectangle",
    "solidity": "area / area of the convex hull",
    "hu1": "first Hu moment invariant",
    "hu2": "second Hu moment invariant",
    "grey_mean": "mean grey level (0-255) of the frame inside the blob, holes out",
    "grey_std": "spread (standard deviation) of those grey levels",
}

#: Features read from the frame's pixels, not from the outline: a brass and a steel part of
#: one outline differ in them under a front light (a backlight shows both dark). ``feeder
#: check`` cannot measure them on a drawn outline, so it leaves their ranges to the images
#: (``feeder check --images``).
PIXEL_FEATURES = frozenset({"grey_mean", "grey_std"})

#: Features that one measurement gives together, cheapest first. ``Locator.locate`` measures
#: a group only when a class it checks ranges over one of its features (the area always: it
#: decides most blobs alone), so a blob's ``features`` hold the area plus what its checks
#: needed; ``Locator.measure_blobs`` (recipe tuning) measures them all.
GROUPS: tuple[tuple[str, ...], ...] = (
    ("area_mm2",),                       # the contour's moments (also the centroid)
    ("holes", "hole_area_mm2"),          # the hole contours (found only when asked for)
    ("hu1", "hu2"),                      # the same moments
    ("perimeter_mm", "circularity"),     # the contour smoothed along itself
    ("aspect", "rectangularity"),        # the minimum-area rectangle
    ("solidity",),                       # the convex hull
    ("grey_mean", "grey_std"),           # the frame's pixels under the blob's mask
)

#: Each feature's group, by index into ``GROUPS`` (its cost rank).
GROUP_OF: dict[str, int] = {name: i for i, group in enumerate(GROUPS) for name in group}

assert set(GROUP_OF) == set(FEATURES), "every feature belongs to one group"
