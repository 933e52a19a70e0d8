"""Blob features a recipe's classes may range over (mm and mm² through the calibration)."""

FEATURES: dict[str, str] = {
    "area_mm2": "blob area in mm²",
    "perimeter_mm": "contour length in mm",
    "circularity": "4·π·area / perimeter², 1 for a disc",
    "aspect": "long side / short side of the minimum-area rectangle",
    "rectangularity": "area / area of the minimum-area rectangle",
    "solidity": "area / area of the convex hull",
    "hu1": "first Hu moment invariant",
    "hu2": "second Hu moment invariant",
}
