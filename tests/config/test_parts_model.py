"""Parts as they are — the part model against the recipe and the cell."""

from __future__ import annotations

from pathlib import Path

import pytest

from feeder_bt.cli.main import main
from tests.support.scenarios import edited_scenario

ROOT = Path(__file__).resolve().parents[2]


_scenario = edited_scenario


def test_check_names_a_class_whose_area_range_cannot_hold_its_outline(tmp_path, capsys):
    """A lens given in inches (``diameter_mm: 2``): exit 2, naming the class and both
    areas, and that every lens would be too small."""
    p = _scenario(tmp_path, "lenses.yaml", ("diameter_mm: 50.8", "diameter_mm: 2"))
    assert main(["check", str(p)]) == 2
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if "vision.classes[0].area_mm2" in ln)
    assert "lens/flat" in line and "[1800, 2300]" in line and "3.138 mm²" in line
    assert "min_area_mm2" in err and "too small" in err


def test_check_accepts_the_shipped_scenarios(capsys):
    files = sorted(str(p) for p in (ROOT / "scenarios").glob("*.yaml"))
    assert main(["check", *files]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("edit", [("area_mm2: [550, 900]", "area_mm2: [3000, 4000]"),
                                  ("area_mm2: [1800, 2300]", "area_mm2: [100, 900]")])
def test_check_names_either_end_of_a_range_that_misses(tmp_path, capsys, edit):
    p = _scenario(tmp_path, "lenses.yaml", edit)
    assert main(["check", str(p)]) == 2
    assert "cannot hold" in capsys.readouterr().err


def _run(path: Path, seconds: float = 150.0) -> dict:
    from feeder_bt.app.run import RunOptions, run_job
    return run_job(RunOptions(scenario=str(path), duration=seconds, fast=True, seed=1,
                              view="none"))


def test_a_symmetric_plate_is_never_misoriented_and_without_its_symmetry_half_are(
        tmp_path, monkeypatch):
    """The chain-link plate (180° symmetric) placed turned to 0 by its long axis: with
    ``symmetry: 2`` none misoriented; without, about half, and the summary line says so
    (``feeder check`` refuses that file: its check is turned off here to show what it
    spares)."""
    from feeder_bt.analysis.summary import summary
    monkeypatch.setattr("feeder_bt.config.checks.check_orientation", lambda sc, ctx: None)
    report = _run(ROOT / "scenarios" / "chain_links.yaml")
    placed = report["parts"]["retrieved"]["link"]
    assert placed > 50 and report["parts"]["misoriented"] == 0
    p = _scenario(tmp_path, "chain_links.yaml", ("    symmetry: 2\n", ""))
    report = _run(p)
    placed, bad = report["parts"]["retrieved"]["link"], report["parts"]["misoriented"]
    assert placed > 50 and 0.3 * placed < bad < 0.7 * placed
    assert f"misoriented {bad}" in summary(report)


def test_symmetry_is_checked_and_sets_the_period(tmp_path):
    from feeder_bt.config.loader import load_scenario
    from feeder_bt.core.errors import ConfigError
    sc, _ = load_scenario(ROOT / "scenarios" / "chain_links.yaml")
    assert sc.parts["link"].period_deg == 180.0 and sc.parts["link"].mirror_symmetric
    p = _scenario(tmp_path, "chain_links.yaml", ("symmetry: 2", "symmetry: 0"))
    with pytest.raises(ConfigError, match=r"chain_links.yaml:\d+: parts.link.symmetry"):
        load_scenario(p)


def test_the_locator_reports_a_symmetric_part_modulo_its_period():
    """The plate's angle comes back in (-90, 90] whatever way round it lies."""
    import numpy as np

    from feeder_bt.config.loader import load_scenario
    from feeder_bt.core.geometry import place_outline, pose_outline
    from feeder_bt.sim.render import Renderer
    from feeder_bt.vision.locator import Locator
    from feeder_bt.vision.pixels import Calibration
    sc, cell = load_scenario(ROOT / "scenarios" / "chain_links.yaml")
    loc = Locator(sc.vision, sc.parts, Calibration(cell.camera.calibration))
    ren = Renderer(cell.camera)
    rng = np.random.default_rng(5)
    loc.set_golden(ren.golden(rng))
    out = pose_outline(sc.parts["link"], "flat")
    for angle in (-170.0, -95.0, 30.0, 120.0, 175.0):
        frame = ren.render([place_outline(out, 240.0, 250.0, angle)], rng)
        res = loc.locate(frame)
        assert len(res.parts) == 1, [d.reason for d in res.rejected]
        got = res.parts[0].angle_deg
        assert -90.0 < got <= 90.0
        assert abs((got - angle + 90.0) % 180.0 - 90.0) < 2.0


# ---------------------------------------------------------------- grips and clearance

FINGERS = """    pick:       # a two-finger gripper closing across the lens
      grips: GRIPS
      fingers: [{offset_mm: [0, 29.5], size_mm: [10, 6]}, {offset_mm: [0, -29.5], size_mm: [10, 6]}]
      clearance_mm: 1
"""


def _finger_lenses(tmp_path: Path, grips: str = "[{angle_deg: 0}]", crowded: bool = False,
                   check: bool = True) -> Path:
    """lenses.yaml with a finger gripper; ``crowded``: on a cell whose hopper lets out
    five times as many parts, a third of them against the one before, on a slower belt."""
    edits = [("    tool_offset: [0, 0, 0]\n",
              "    tool_offset: [0, 0, 0]\n" + FINGERS.replace("GRIPS", grips))]
    if not check:
        edits.append(("  orientation: none", "  orientation: none\n  check_clearance: false"))
    if crowded:
        cell = (ROOT / "cells" / "sim.yaml").read_text().replace(
            "release_per_mm: 0.030", "release_per_mm: 0.150") + "\nsim:\n  clump_prob: 0.3\n"
        (tmp_path / "crowded.yaml").write_text(cell)
        edits += [("horizontal_mm_s: 150", "horizontal_mm_s: 100")]
    p = _scenario(tmp_path, "lenses.yaml", *edits)
    if crowded:
        p.write_text(p.read_text().replace(f"cell: {ROOT / 'cells'}/sim.yaml",
                                           f"cell: {tmp_path / 'crowded.yaml'}"))
    return p


def _three_lenses(path: Path, gap_mm: float):
    """A lens with a neighbour ``gap_mm`` away along x and another along y: its results."""
    import numpy as np

    from feeder_bt.config.loader import load_scenario
    from feeder_bt.core.geometry import place_outline, pose_outline
    from feeder_bt.sim.render import Renderer
    from feeder_bt.vision.locator import Locator
    from feeder_bt.vision.pixels import Calibration
    sc, cell = load_scenario(path)
    loc = Locator(sc.vision, sc.parts, Calibration(cell.camera.calibration))
    ren = Renderer(cell.camera)
    rng = np.random.default_rng(1)
    loc.set_golden(ren.golden(rng))
    out = pose_outline(sc.parts["lens"], "flat")
    step = 50.8 + gap_mm
    res = loc.locate(ren.render([place_outline(out, 200.0, 250.0, 0.0),
                                 place_outline(out, 200.0, 250.0 + step, 0.0),
                                 place_outline(out, 200.0 + step, 250.0, 0.0)], rng))
    return {(round(d.x_mm), round(d.y_mm)): d for d in res.parts + res.rejected}


def test_a_part_whose_every_grip_is_blocked_is_not_offered(tmp_path):
    """Fingers closing along y need 26.5-32.5 mm (+1 clear) each side of the centre: a
    neighbour 5 mm away along y blocks them; 9 mm away it does not."""
    one = _finger_lenses(tmp_path)
    dets = _three_lenses(one, 5.0)
    assert dets[(200, 250)].reason == "gripper blocked" and dets[(200, 250)].part == "lens"
    # the one beside it along y is blocked by it the same way; the one along x is free
    assert dets[(200, 306)].reason == "gripper blocked" and dets[(256, 250)].reason == ""
    assert all(d.reason == "" for d in _three_lenses(one, 9.0).values())
    # a second grip, turned 90°, is blocked by the neighbour along x: still not offered;
    # with a neighbour along y only, both are offered turned
    two = _finger_lenses(tmp_path, "[{angle_deg: 0}, {angle_deg: 90}]")
    assert _three_lenses(two, 5.0)[(200, 250)].reason == "gripper blocked"
    import numpy as np

    from feeder_bt.config.loader import load_scenario
    from feeder_bt.core.geometry import place_outline, pose_outline
    from feeder_bt.sim.render import Renderer
    from feeder_bt.vision.locator import Locator
    from feeder_bt.vision.pixels import Calibration
    sc, cell = load_scenario(two)
    loc = Locator(sc.vision, sc.parts, Calibration(cell.camera.calibration))
    ren = Renderer(cell.camera)
    rng = np.random.default_rng(2)
    loc.set_golden(ren.golden(rng))
    out = pose_outline(sc.parts["lens"], "flat")
    res = loc.locate(ren.render([place_outline(out, 200.0, 250.0, 0.0),
                                 place_outline(out, 200.0, 305.8, 0.0)], rng))
    assert [round(d.grip_deg) for d in res.parts] == [90, 90]     # each blocks the other along y
    # without the check every lens is offered at its first grip
    off = _finger_lenses(tmp_path, check=False)
    assert all(d.reason == "" and d.grip_deg == 0 for d in _three_lenses(off, 5.0).values())


def test_a_washer_is_gripped_on_its_ring_never_over_its_hole(tmp_path, monkeypatch):
    """The washer's cup grips sit on the ring: none over the hole; gripped at its
    centroid (no ``pick``), every washer grip is over the hole and misses: the cell stops
    after ``max_failed_picks`` of them in a row (the slugs between picked well), and without
    that limit misses every washer. ``feeder check`` names that file first (its check is
    turned off below to show what it spares)."""
    from feeder_bt.config import check_files
    rep = _run(ROOT / "scenarios" / "washers.yaml", 200.0)
    assert rep["parts"]["retrieved"]["washer"] > 100
    assert rep["parts"]["grip_misses"]["grip_on_hole"] == 0
    no_pick = ("    pick:\n      grips: [{offset_mm: [8.5, 0]}, {offset_mm: [0, 8.5]}, "
               "{offset_mm: [-8.5, 0]}, {offset_mm: [0, -8.5]}]\n      cup_radius_mm: 3\n", "")
    out = check_files([str(_scenario(tmp_path, "washers.yaml", no_pick))])
    assert len(out) == 1 and "lies in a hole" in out[0]
    monkeypatch.setattr("feeder_bt.config.checks.check_grips", lambda sc, ctx: None)
    rep = _run(_scenario(tmp_path, "washers.yaml", no_pick), 200.0)
    assert rep["state"] == "FAULT" and "20 picks of washer" in rep["fault"]
    assert rep["parts"]["missed"] == rep["parts"]["grip_misses"]["grip_on_hole"] >= 20
    p = _scenario(tmp_path, "washers.yaml", no_pick,
                  ("  tracking: true\n", "  tracking: true\n  max_failed_picks: 0\n"))
    rep = _run(p, 200.0)
    assert rep["parts"]["retrieved"]["washer"] == 0
    assert rep["parts"]["grip_misses"]["grip_on_hole"] > 100


def test_on_a_crowded_belt_grips_on_a_neighbour_fall_to_zero(tmp_path):
    """A crowded belt, fingers across the lens: without the clearance check some picks
    land on a neighbour; with it none do, and blocked parts were not offered."""
    off = _run(_finger_lenses(tmp_path, crowded=True, check=False), 300.0)
    on = _run(_finger_lenses(tmp_path, crowded=True), 300.0)
    assert off["parts"]["grip_misses"]["grip_on_neighbour"] >= 4
    assert on["parts"]["grip_misses"]["grip_on_neighbour"] == 0
    assert on["vision"]["gripper_blocked"] > 5 and off["vision"]["gripper_blocked"] == 0
    assert on["parts"]["retrieved"]["lens"] >= 0.97 * off["parts"]["retrieved"]["lens"]


def test_grips_are_mirrored_with_a_face_down_part():
    from feeder_bt.core.model import Finger, Grip, PickSpec
    from feeder_bt.robot.gripper import footprint, grip_poses
    pick = PickSpec(grips=[Grip((10.0, 5.0), 30.0)], fingers=[Finger((0.0, 4.0), (2.0, 2.0))])
    (x, y, a), = grip_poses(pick, 100.0, 50.0, 90.0, mirrored=False)
    assert (x, y, a) == pytest.approx((95.0, 60.0, 120.0))
    (x, y, a), = grip_poses(pick, 100.0, 50.0, 90.0, mirrored=True)
    assert (x, y, a) == pytest.approx((105.0, 60.0, 60.0))
    box, = footprint(pick, 0.0, 0.0, 90.0)
    assert box.mean(axis=0) == pytest.approx((-4.0, 0.0))


# ---------------------------------------------------------------- orientation: outline

def _brackets(**part_edits):
    import dataclasses

    from feeder_bt.config.loader import load_scenario
    sc, cell = load_scenario(ROOT / "scenarios" / "brackets_frontlit.yaml")
    vision = dataclasses.replace(sc.vision, orientation="outline")
    if part_edits:
        sc.parts["bracket"] = dataclasses.replace(sc.parts["bracket"], **part_edits)
    return sc, cell, vision


def _locate_layout(sc, cell, vision, outlines, seed):
    """Draw light parts at (x, y, angle, face-down) on the front-lit camera; the result
    nearest each, in order."""
    import numpy as np

    from feeder_bt.core.geometry import place_outline
    from feeder_bt.sim.render import Renderer
    from feeder_bt.vision.locator import Locator
    from feeder_bt.vision.pixels import Calibration
    loc = Locator(vision, sc.parts, Calibration(cell.camera.calibration))
    ren = Renderer(cell.camera)
    rng = np.random.default_rng(seed)
    loc.set_golden(ren.golden(rng))
    frame = ren.render([place_outline(o, x, y, a) for o, (x, y, a) in outlines], rng)
    res = loc.locate(frame)
    found = res.parts + res.rejected
    return [min(found, key=lambda d: np.hypot(d.x_mm - x, d.y_mm - y))
            for _, (x, y, _) in outlines]


def test_face_down_l_brackets_over_360_are_located_with_their_face_and_angle():
    """Light L-brackets, half face-down, turned over 360°: every one
    located with the right face (``mirrored``) and its angle within 2°."""
    import numpy as np

    from feeder_bt.core.geometry import pose_outline, wrap_deg
    sc, cell, vision = _brackets()
    up = pose_outline(sc.parts["bracket"], "flat")
    down = np.column_stack([up[::-1, 0], -up[::-1, 1]])     # as a mirror pose lies
    rng = np.random.default_rng(27)
    errors = []
    for frame in range(8):
        lay = [(k % 2 == 1, (150.0 + 90 * (k % 4), 110.0 + 110 * (k // 4),
                             float(rng.uniform(-180, 180)))) for k in range(12)]
        dets = _locate_layout(sc, cell, vision, [(down if m else up, p) for m, p in lay],
                              seed=frame)
        for (m, (_, _, a)), d in zip(lay, dets, strict=True):
            assert d.reason == "" and d.part == "bracket", d.reason
            assert d.features["mirrored"] == (1.0 if m else 0.0)
            errors.append(abs(wrap_deg(d.angle_deg - a)))
    assert len(errors) == 96 and max(errors) < 2.0


def test_a_nearly_symmetric_outline_is_rejected_not_guessed():
    """An L with equal legs is its own mirror image turned: face up and face down score
    the same, so it is rejected with that reason; declared mirror_symmetric, it is
    located (its face does not matter) at the right angle."""

    from feeder_bt.core.geometry import pose_outline, wrap_deg
    from feeder_bt.core.model import Shape
    equal = Shape(kind="polygon",
                  points_mm=[(-13.0, -13.0), (22.0, -13.0), (22.0, -3.0), (-3.0, -3.0),
                             (-3.0, 22.0), (-13.0, 22.0)])
    sc, cell, vision = _brackets(shape=equal)
    vision.classes[0].ranges["area_mm2"] = (500.0, 800.0)
    out = pose_outline(sc.parts["bracket"], "flat")
    places = [(160.0 + 120 * k, 200.0, a) for k, a in enumerate((-120.0, 10.0, 95.0))]
    dets = _locate_layout(sc, cell, vision, [(out, p) for p in places], seed=1)
    assert all("orientation ambiguous" in d.reason and d.part is None for d in dets), \
        [d.reason for d in dets]
    sc, cell, vision = _brackets(shape=equal, mirror_symmetric=True)
    vision.classes[0].ranges["area_mm2"] = (500.0, 800.0)
    dets = _locate_layout(sc, cell, vision, [(out, p) for p in places], seed=1)
    for d, (_, _, a) in zip(dets, places, strict=True):
        assert d.reason == "" and abs(wrap_deg(d.angle_deg - a)) < 2.0


# ---------------------------------------------------------------- splitting touching parts

def _touching_pairs(name: str, part: str, pose: str, split: bool, frames: int = 10,
                    apart: tuple[float, float] = (0.93, 0.99)):
    """Frames of three pairs of touching (slightly overlapping) parts, turned at random,
    their centres ``apart`` times the outline's circumscribed diameter: (parts in the
    truth, offered within 2 mm of one with the right part, offered wrong)."""
    import dataclasses
    import math

    import numpy as np

    from feeder_bt.config.loader import load_scenario
    from feeder_bt.core.geometry import place_outline, pose_outline
    from feeder_bt.sim.render import Renderer
    from feeder_bt.vision.locator import Locator
    from feeder_bt.vision.pixels import Calibration
    sc, cell = load_scenario(ROOT / "scenarios" / f"{name}.yaml")
    ren = Renderer(cell.camera)
    out = pose_outline(sc.parts[part], pose)
    r = float(np.nanmax(np.hypot(out[:, 0], out[:, 1])))
    loc = Locator(dataclasses.replace(sc.vision, split_touching=split), sc.parts,
                  Calibration(cell.camera.calibration))
    rng = np.random.default_rng(7)
    loc.set_golden(ren.golden(rng))
    total = ok = wrong = 0
    for _ in range(frames):
        truth = []
        for k in range(3):
            th, d = rng.uniform(0, 2 * math.pi), 2 * r * rng.uniform(*apart)
            for s in (-0.5, 0.5):
                truth.append((170 + 150 * k + s * d * math.cos(th), 240 + s * d * math.sin(th),
                              float(rng.uniform(-180, 180))))
        res = loc.locate(ren.render([place_outline(out, x, y, a) for x, y, a in truth], rng))
        total += len(truth)
        for det in res.parts:
            dist = min(math.hypot(x - det.x_mm, y - det.y_mm) for x, y, _ in truth)
            ok += dist < 2.0 and det.part == part
            wrong += not (dist < 2.0 and det.part == part)
    return total, ok, wrong


def test_splitting_touching_parts_offers_more_and_none_wrong():
    """With ``split_touching`` touching lenses and washers are cut apart and
    offered, each within 2 mm of a true part; off (the default) they are rejected."""
    total, ok, wrong = _touching_pairs("lenses", "lens", "flat", split=False)
    assert (ok, wrong) == (0, 0)
    total, ok, wrong = _touching_pairs("lenses", "lens", "flat", split=True)
    assert ok >= 0.95 * total and wrong == 0
    total, ok, wrong = _touching_pairs("washers", "washer", "flat", split=True)
    assert ok >= 0.5 * total and wrong == 0            # holes kept: never taken for slugs
    before = _touching_pairs("squares", "square", "face_up", False, 8, (0.8, 0.95))
    after = _touching_pairs("squares", "square", "face_up", True, 8, (0.8, 0.95))
    assert after[1] > before[1] and after[2] == before[2] == 0


def test_the_locators_pixel_table_is_the_lens_mapping():
    """``Locator._mapping`` (the calibration's ``PixelGrid``: the exact mapping every 4 px,
    read bilinearly) against the exact mapping, on the simulated cell's lens and tilt, at
    points anywhere in the window and half a pixel beyond it: positions within 0.001 mm,
    local scales within 1e-5."""
    import numpy as np

    from feeder_bt.config.loader import load_scenario
    from feeder_bt.vision.locator import Locator
    from feeder_bt.vision.pixels import Calibration, PixelGrid
    sc, cell = load_scenario(ROOT / "scenarios" / "squares.yaml")
    cal = Calibration(cell.camera.calibration)
    assert not cal.linear                       # the cell has a lens model
    loc = Locator(sc.vision, sc.parts, cal)
    shape = (cell.camera.height_px, cell.camera.width_px)
    grid = loc._mapping(shape)
    assert isinstance(grid, PixelGrid) and loc._mapping(shape) is grid    # built once
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.5, -0.5], [shape[1] - 0.5, shape[0] - 0.5], (4000, 2))
    near, scale = grid.px_to_mm_scale(pts)
    exact, exact_scale = cal.px_to_mm_scale(pts)
    assert np.abs(near - exact).max() < 0.001
    assert np.abs(scale / exact_scale - 1).max() < 1e-5
