"""``feeder check SCENARIO --images DIR``: the recipe on sample images before a run.

A scenario can pass the YAML checks and still locate nothing on the cell (class ranges
measured at another threshold, the wrong ``foreground``). This runs the recipe on every
image in DIR (``golden.png`` there is the golden image, if the recipe subtracts one) and
reports what it finds per image, the parts per class over all, and for images with no
part why (``feeder_bt.vision.diagnose``). An image (the golden one too) of another size
than the cell's camera takes is named, one line each: the calibration maps the camera's
pixels, so its finds say nothing of a run. Exit 0 if some image has a part and every image
is the camera's size, 1 otherwise.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from feeder_bt.cli.inputs import check_size, load_golden, scenario_locator
from feeder_bt.core.images import BadInput, read_image
from feeder_bt.vision.diagnose import why_nothing

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
GOLDEN_NAME = "golden.png"


def check_images(scenario: str, folder: str) -> int:
    """Run ``scenario``'s recipe on the images of ``folder``; print the findings."""
    d = Path(folder)
    if not d.is_dir():
        raise BadInput(f"{d}: --images needs a folder of images")
    paths = sorted(p for p in d.iterdir()
                   if p.suffix.lower() in IMAGE_SUFFIXES and p.name != GOLDEN_NAME)
    if not paths:
        raise BadInput(f"{d}: no images ({', '.join(IMAGE_SUFFIXES)}) besides {GOLDEN_NAME}")
    _, cell, locator = scenario_locator(scenario)
    cam = cell.camera
    golden_path = d / GOLDEN_NAME
    golden = load_golden(locator, str(golden_path) if golden_path.is_file() else None,
                         "feeder check")
    wrong: list[str] = []

    def size(name: str, img) -> None:
        h, w = img.shape[:2]
        if (w, h) != (cam.width_px, cam.height_px):
            wrong.append(name)
            print(f"  {name}: {w}x{h} px, but the cell's camera takes {cam.width_px}x"
                  f"{cam.height_px} px ({cell.path}: camera.width_px, height_px): not this "
                  f"camera's image, its mm would be wrong")
    found: Counter[str] = Counter()
    rejected: Counter[str] = Counter()
    empty = 0
    print(f"{scenario}: recipe on {len(paths)} image(s) in {d}"
          + (f" (golden image {golden_path.name})" if golden is not None else ""))
    if golden is not None:
        size(golden_path.name, golden)
    for p in paths:
        img = read_image(p)
        check_size(str(p), img, golden)
        size(p.name, img)
        result = locator.locate(img)
        found.update(f"{det.part}/{det.pose}" for det in result.parts)
        rejected.update(det.reason for det in result.rejected)
        print(f"  {p.name}: {len(result.parts)} part(s), {len(result.rejected)} rejected")
        if not result.parts:
            empty += 1
            for line in why_nothing(locator, img, result, golden):
                print(f"    why: {line}")
    classes = [f"{c.part}/{c.pose}" for c in locator.recipe.classes]
    print("  parts per class: " + ", ".join(f"{c} {found.get(c, 0)}" for c in classes))
    never = [c for c in classes if not found.get(c)]
    if never:
        print(f"  never matched: {', '.join(never)}")
    if wrong:
        print(f"  {len(wrong)} image(s) not {cam.width_px}x{cam.height_px} px, the camera's: "
              f"check the recipe on the cell's own frames")
    if not found:
        print(f"  NOTHING LOCATED in {len(paths)} image(s): this recipe would feed nothing")
        return 1
    if wrong:
        return 1
    print(f"  ok: parts in {len(paths) - empty} of {len(paths)} image(s)")
    return 0
