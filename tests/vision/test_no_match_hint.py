"""The "why no part" hint: reasons grouped by kind (not by their text, whose figures differ
blob to blob), one short line, and touching parts called touching parts, not a belt that
passes the threshold."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from feeder_bt.config import load_scenario
from feeder_bt.core.geometry import place_outline, pose_outline
from feeder_bt.sim.render import Renderer
from feeder_bt.vision.diagnose import why_nothing
from feeder_bt.vision.locator import Detection, LocateResult, Locator
from feeder_bt.vision.pixels import Calibration
from feeder_bt.vision.watch import LINE_CHARS, RecipeWatch, reasons_line

ROOT = Path(__file__).resolve().parents[2]


class _Stats:
    def __init__(self) -> None:
        self.events: list[tuple[float, str, dict]] = []

    def emit(self, t: float, kind: str, /, **data) -> None:
        self.events.append((t, kind, data))


def _frame(reasons: list[str]) -> LocateResult:
    dets = [Detection(None, None, False, 0.0, 0.0, 0.0, 0.0, 0.0, {"area_mm2": 700.0}, r)
            for r in reasons]
    return LocateResult(parts=[], rejected=dets, ms=0.0)


def test_reasons_that_differ_only_in_their_figures_are_one_kind():
    """Each blob's outline overlap is its own figure: grouped by text, the commonest kind
    (two a frame) lost to the "touches border" blob (one a frame) and the report listed
    one reason per figure."""
    watch, stats = RecipeWatch(), _Stats()
    for k in range(60):
        watch.feed(float(k), _frame([
            "touches border",
            f"no class (outline does not match (overlap 0.{10 + k:02d}))",
            f"no class (orientation ambiguous (overlap 0.{40 + k:02d} vs 0.{30 + k:02d}: the "
            f"outline is nearly symmetric))",
            f"no class (outline does not match (overlap 0.{70 - k:02d}))"]), stats)
    summary = watch.summary()
    assert summary["reasons"] == {"no class (outline does not match)": 120,
                                  "touches border": 60,
                                  "no class (orientation ambiguous)": 60}
    assert summary["feature"] == "no class (outline does not match)"
    alarm = next(d for _, kind, d in stats.events if kind == "vision_no_match")
    assert alarm["feature"] == "no class (outline does not match)"
    assert len(alarm["hint"]) <= LINE_CHARS


def test_the_reasons_line_is_short_however_many_kinds():
    reasons = {f"no class; nearest part_{i}/flat: area_mm2": 1000 - i for i in range(80)}
    line = reasons_line(reasons)
    assert len(line) <= LINE_CHARS and line.endswith(" more")
    assert line.startswith("no class; nearest part_0/flat: area_mm2 1000")


def test_the_watch_calls_blobs_of_several_parts_touching_parts():
    watch, stats = RecipeWatch(), _Stats()
    for k in range(40):
        watch.feed(float(k), _frame([f"no class; nearest slug/flat: area_mm2 {1400 + k} not "
                                     f"in [420, 490]"]), stats)
    hint = next(d for _, kind, d in stats.events if kind == "vision_no_match")["hint"]
    assert "parts touching" in hint and "split_touching" in hint and len(hint) <= LINE_CHARS


def test_a_clump_of_touching_discs_is_not_a_belt_passing_the_threshold():
    """Slugs (24 mm discs) packed edge to edge over more than half the image, clear of its
    border: one blob of hundreds of slugs. The hint names touching parts; the old one asked
    whether the parts were lighter than the belt."""
    sc, cell = load_scenario(ROOT / "scenarios" / "washers.yaml")
    renderer = Renderer(cell.camera)
    locator = Locator(sc.vision, sc.parts, Calibration(cell.camera.calibration))
    rng = np.random.default_rng(4)
    golden = renderer.golden(rng)
    locator.set_golden(golden)
    slug = pose_outline(sc.parts["slug"], "flat")
    outlines = [place_outline(slug, x, y, 0.0)
                for x in np.arange(110.0, 531.0, 23.0) for y in np.arange(15.0, 591.0, 23.0)]
    img = renderer.render(outlines, rng)
    result = locator.locate(img)
    assert result.parts == [] and len(result.rejected) == 1
    assert result.rejected[0].features["area_mm2"] > 0.5 * img.shape[0] * img.shape[1]
    why = why_nothing(locator, img, result, golden)
    assert any("parts touching each other" in ln and "split_touching" in ln for ln in why), why
    assert not any("than the belt" in ln for ln in why), why
    assert all(len(ln) <= LINE_CHARS for ln in why)


def test_an_ambiguous_or_unmatched_outline_says_what_to_give():
    """Blobs rejected by ``orientation: outline``: the hint says what the recipe lacks
    (the part's symmetry, a lower least overlap), in one short line."""
    for reason, said in [("no class (orientation ambiguous (overlap 0.93 vs 0.93: the "
                          "outline is nearly symmetric))", "give the part's symmetry"),
                         ("no class (outline does not match (overlap 0.62 < min_iou 0.75))",
                          "outline_match.min_iou")]:
        watch, stats = RecipeWatch(), _Stats()
        for k in range(40):
            watch.feed(float(k), _frame([reason]), stats)
        hint = next(d for _, kind, d in stats.events if kind == "vision_no_match")["hint"]
        assert said in hint and len(hint) <= LINE_CHARS, hint
