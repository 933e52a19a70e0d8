"""Labelled sample images for ``feeder teach``: COCO JSON as CVAT, Label Studio and labelme
export it, and folders of images of one part each.

A COCO file's ``images[]`` are matched to the image files given by file name (the
basename: exporters prefix folders differently), its ``annotations[]`` give each part's
box ``[x, y, w, h]`` px (and maybe a polygon, unused: the blob's own outline is better
measured than a hand-drawn one), and its ``categories[]`` are ``part`` or ``part/pose``.
Every mistake is one line naming the file and what is wrong (``BadInput``, exit 2).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from feeder_bt.core.images import BadInput, read_image

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")
NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
DEFAULT_POSE = "flat"


@dataclass
class Box:
    """One labelled part: its class and its box (px, inclusive-exclusive)."""

    part: str
    pose: str
    x: float
    y: float
    w: float
    h: float

    @property
    def cls(self) -> tuple[str, str]:
        return self.part, self.pose

    def contains(self, u: float, v: float) -> bool:
        return self.x <= u <= self.x + self.w and self.y <= v <= self.y + self.h

    def touches_border(self, width: int, height: int, margin: float = 2.0) -> bool:
        """A part cut by the image's edge: the locator leaves it for the next frame, so it
        is neither a sample nor a miss."""
        return (self.x <= margin or self.y <= margin or self.x + self.w >= width - margin
                or self.y + self.h >= height - margin)


@dataclass
class Sample:
    """One image and what is known of it: labelled boxes, or (``part`` set) that every
    blob in it is that part."""

    path: Path
    image: np.ndarray
    boxes: list[Box] = field(default_factory=list)
    part: tuple[str, str] | None = None

    @property
    def name(self) -> str:
        return self.path.name


def split_category(name: str, where: str) -> tuple[str, str]:
    """``part`` or ``part/pose`` -> (part, pose); names must be YAML-friendly identifiers."""
    part, _, pose = name.strip().partition("/")
    pose = pose or DEFAULT_POSE
    for what, v in (("part", part), ("pose", pose)):
        if not NAME_RE.match(v):
            raise BadInput(f"{where}: category {name!r}: the {what} name {v!r} must be letters, "
                           "digits and _ (not starting with a digit), written part or part/pose")
    return part, pose


def load_coco(labels: str | Path, images: list[str | Path]) -> list[Sample]:
    """The samples of ``images`` with their boxes from the COCO file ``labels``.

    An image the file does not list is an error (a forgotten export); an image listed
    but not given is skipped (a subset was asked for)."""
    path = Path(labels)
    if not path.is_file():
        raise BadInput(f"{path}: labels file not found")
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise BadInput(f"{path}: not JSON ({e})") from None
    if not isinstance(doc, dict):
        raise BadInput(f"{path}: expected a COCO object with images, annotations, categories")
    for key in ("images", "annotations", "categories"):
        if not isinstance(doc.get(key), list):
            raise BadInput(f"{path}: no {key}[] list: is this a COCO export?")
    cats: dict[int, tuple[str, str]] = {}
    for i, c in enumerate(doc["categories"]):
        if not isinstance(c, dict) or "id" not in c or not isinstance(c.get("name"), str):
            raise BadInput(f"{path}: categories[{i}]: needs an id and a name")
        cats[c["id"]] = split_category(c["name"], f"{path}: categories[{i}]")
    by_id: dict[object, str] = {}
    for i, im in enumerate(doc["images"]):
        if not isinstance(im, dict) or "id" not in im or not isinstance(im.get("file_name"), str):
            raise BadInput(f"{path}: images[{i}]: needs an id and a file_name")
        by_id[im["id"]] = Path(im["file_name"].replace("\\", "/")).name
    boxes: dict[str, list[Box]] = {name: [] for name in by_id.values()}
    for i, a in enumerate(doc["annotations"]):
        where = f"{path}: annotations[{i}]"
        if not isinstance(a, dict):
            raise BadInput(f"{where}: not an object")
        if a.get("image_id") not in by_id:
            raise BadInput(f"{where}: image_id {a.get('image_id')!r} is not in images[]")
        if a.get("category_id") not in cats:
            raise BadInput(f"{where}: unknown category_id {a.get('category_id')!r} "
                           f"(categories: {', '.join(str(k) for k in cats)})")
        bbox = a.get("bbox")
        if not (isinstance(bbox, list) and len(bbox) == 4
                and all(isinstance(v, int | float) for v in bbox)) or bbox[2] <= 0 or bbox[3] <= 0:
            raise BadInput(f"{where}: bbox must be [x, y, width, height] px with width and "
                           f"height > 0, got {bbox!r}")
        part, pose = cats[a["category_id"]]
        boxes[by_id[a["image_id"]]].append(Box(part, pose, *(float(v) for v in bbox)))
    out = []
    for img in images:
        p = Path(img)
        listed = _listed(p.name, boxes, path)
        out.append(Sample(p, read_image(p), boxes[listed]))
    return out


def _listed(name: str, listed: dict[str, list[Box]], path: Path) -> str:
    """The ``images[]`` name of the image file ``name``: the same, or (Label Studio
    prefixes uploads with a hash and a dash) the one name ending in ``-NAME``."""
    if name in listed:
        return name
    prefixed = [n for n in listed if n.endswith("-" + name)]
    if len(prefixed) == 1:
        return prefixed[0]
    raise BadInput(f"{path}: no image named {name} in images[]"
                   + (f" (several end in -{name})" if prefixed else ""))


def load_part_dir(spec: str) -> list[Sample]:
    """``NAME=DIR`` (or ``NAME/POSE=DIR``): every image in DIR shows that part alone, so
    every whole blob in it is one."""
    name, sep, folder = spec.partition("=")
    if not sep or not name or not folder:
        raise BadInput(f"--part {spec!r}: expected NAME=DIR (or NAME/POSE=DIR)")
    cls = split_category(name, f"--part {spec}")
    d = Path(folder)
    if not d.is_dir():
        raise BadInput(f"{d}: --part folder not found")
    files = sorted(f for f in d.iterdir() if f.suffix.lower() in IMAGE_SUFFIXES)
    if not files:
        raise BadInput(f"{d}: no images (PNG, JPG or BMP) in the --part folder")
    return [Sample(f, read_image(f), part=cls) for f in files]
