"""Checks that need more than one key at a time: inside a cell description (reach, target,
encoder, Galil wiring), inside a scenario (pose probabilities, names of parts and poses,
adjuster parameters) and of a scenario against the cell it runs on (speeds, camera window).

Each problem is listed with ``ctx.add_problem`` and the checks go on, so every mistake of a
file is reported at once; a check that still raises ``ctx.error(...)`` stops only itself.
"""

from __future__ import annotations

import math

from feeder_bt.config.area_checks import check_class_areas, check_class_rulers
from feeder_bt.config.special import part_size_mm
from feeder_bt.config.tables import ADJUST_ORDER, ADJUST_PARAMS, PROBABILITY_TOLERANCE, _num
from feeder_bt.config.walker import _Ctx, _suggest
from feeder_bt.core.model import (
    AdjustParams,
    CellSpec,
    Scenario,
    belt_window,
    reach_over_belt,
)
from feeder_bt.policy.adjusters import ADJUSTERS, AdjusterParamError
from feeder_bt.vision.features import FEATURES


def _check_cell(cell: CellSpec, ctx: _Ctx) -> None:
    """Cross-field checks inside a cell description."""
    r = cell.robot
    if r.inner_reach_mm >= r.reach_mm:
        ctx.add_problem("robot.inner_reach_mm", f"must be < robot.reach_mm "
                                                f"({_num(r.reach_mm)}), got "
                                                f"{_num(r.inner_reach_mm)}")
    _check_window(cell, ctx)
    t = cell.camera.target
    if t is not None:
        if min(t.board) < 2:
            ctx.add_problem("camera.target.board", f"needs at least 2 points per row and 2 "
                                                   f"rows, got {t.board[0]}x{t.board[1]}")
        if t.kind == "charuco" and t.marker_mm >= t.pitch_mm:
            ctx.add_problem("camera.target.marker_mm", f"must be < pitch_mm "
                                                       f"({_num(t.pitch_mm)}), got "
                                                       f"{_num(t.marker_mm)}")
    p = cell.camera.pylon
    if p.trigger_signal is not None:
        sig = cell.io.get(p.trigger_signal)
        if sig is None or sig.dir != "out":
            outs = ", ".join(n for n, s in cell.io.items() if s.dir == "out") or "none"
            ctx.add_problem("camera.pylon.trigger_signal",
                            f"{p.trigger_signal!r} is not an output in io: (outputs: {outs})")
        elif p.trigger == "Software":
            ctx.add_problem("camera.pylon.trigger_signal",
                            "pulses a line: set camera.pylon.trigger to Line1 (or Line2, Line3)")
    if p.trigger == "Software":
        for key, what in (("line_debouncer_us", "filters the trigger line"),
                          ("trigger_delay_us", "delays a line trigger, never a software one")):
            if getattr(p, key) is not None:
                ctx.add_problem(f"camera.pylon.{key}", f"{what}: set camera.pylon.trigger "
                                                       "to Line1 (or Line2, Line3)")
    e = cell.encoder
    if e.robot_start >= 2 ** e.robot_bits:
        ctx.add_problem("encoder.robot_start", f"must be < 2**robot_bits "
                                               f"({2 ** e.robot_bits}), got {e.robot_start}")
    if e.drift_warn_mm > e.drift_limit_mm:
        ctx.add_problem("encoder.drift_warn_mm",
                        f"must be <= drift_limit_mm ({_num(e.drift_limit_mm)}), "
                        f"got {_num(e.drift_warn_mm)}")
    s = cell.sim
    if s.belt_mu_static > 0 and s.belt_mu_kinetic <= 0:
        ctx.add_problem("sim.belt_mu_kinetic", "must be > 0 while sim.belt_mu_static is: a "
                                               "part sliding without friction never stops")
    if 0 < s.belt_mu_static < s.belt_mu_kinetic:      # a static 0 turns slip off
        ctx.add_problem("sim.belt_mu_kinetic",
                        f"must be <= sim.belt_mu_static ({_num(s.belt_mu_static)}): sliding "
                        f"friction is never more than sticking friction, got "
                        f"{_num(s.belt_mu_kinetic)}")
    _check_galil(cell, ctx)


def window_problems(cell: CellSpec, up: float, down: float, pick: float) -> list[str]:
    """What is wrong with a belt window (belt-frame x, mm) on this cell: its order, and a
    limit outside the arm's reach over the belt (where V+ would answer -610 or -9004 for
    every part). Shared by the cell's checks and commissioning's taught window."""
    span = reach_over_belt(cell)
    out = []
    if not up < pick <= down:
        out.append(f"needs upstream < pick limit <= downstream, got {_num(up)}, "
                   f"{_num(pick)}, {_num(down)} mm")
    for name, x in (("upstream", up), ("downstream", down)):
        if not span[0] - 0.5 <= x <= span[1] + 0.5:
            out.append(f"the {name} limit {_num(x)} mm is outside the arm's reach over the "
                       f"belt ({_num(round(span[0], 1))}-{_num(round(span[1], 1))} mm, from "
                       "robot.base_mm, reach_mm and the horizontal belt)")
    return out


def _check_window(cell: CellSpec, ctx: _Ctx) -> None:
    r = cell.robot
    if r.belt_window_mm is None and r.pick_limit_mm is None:
        return
    key = "robot.belt_window_mm" if r.belt_window_mm is not None else "robot.pick_limit_mm"
    for problem in window_problems(cell, *belt_window(cell)):
        ctx.add_problem(key, problem)


# Galil wiring (docs/real-cell.md): I/O bits start at 1, the input monitor reports
# inputs 1-8, or 1-16 on a card with 16 (``galil.inputs``: TI 1 is only valid on a 5-8 axis
# card, Galil command reference, TI), and the DMC-21x3 latches each axis from its own input.
GALIL_MAX_INPUT = 16
GALIL_MAX_OUTPUT = 16


def _check_galil(cell: CellSpec, ctx: _Ctx) -> None:
    g = cell.galil
    if g.inputs not in (8, GALIL_MAX_INPUT):
        ctx.add_problem("galil.inputs", f"8 (a 1-4 axis card) or 16 (a 5-8 axis card), "
                                        f"got {g.inputs!r}")
    for name, sig in cell.io.items():
        if sig.controller != "galil":
            continue
        top = GALIL_MAX_INPUT if sig.dir == "in" else GALIL_MAX_OUTPUT
        if not 1 <= sig.bit <= top:
            ctx.add_problem(f"io.{name}.bit", f"Galil {'inputs' if sig.dir == 'in' else 'outputs'}"
                                              f" are numbered 1-{top}, got {sig.bit}")
        elif sig.dir == "in" and sig.bit > g.inputs:
            ctx.add_problem(f"io.{name}.bit", f"input {sig.bit} on a card with galil.inputs "
                                              f"{g.inputs}; inputs 9-16 need a 5-8 axis card "
                                              f"(galil.inputs: 16)")
    axis = str(g.latch_axis).upper()
    if len(axis) != 1 or axis not in "ABCDEFGH":
        ctx.add_problem("galil.latch_axis", f"one axis letter A-H, got {g.latch_axis!r}")
        return
    fixed = "ABCDEFGH".index(axis) + 1
    if g.latch_input is not None and g.latch_input != fixed:
        ctx.add_problem("galil.latch_input", f"the DMC-21x3 latches axis {axis} from input "
                                             f"{fixed} only (fixed per axis); wire the camera "
                                             f"trigger there, got {g.latch_input}")


def _check_scenario(sc: Scenario, ctx: _Ctx) -> None:
    """Checks that need more than one field of the scenario (but not the cell)."""
    for pname, part in sc.parts.items():
        ppath = f"parts.{pname}.poses"
        if not part.poses:
            ctx.add_problem(ppath, "a part needs at least one stable pose")
            continue
        total = math.fsum(p.probability for p in part.poses.values())
        if abs(total - 1.0) > PROBABILITY_TOLERANCE:
            terms = " + ".join(f"{n} {_num(p.probability)}" for n, p in part.poses.items())
            ctx.add_problem(ppath, f"pose probabilities must sum to 1, got {total:.6g} "
                                   f"({terms})")
        if not any(p.pickable for p in part.poses.values()):
            ctx.add_problem(ppath, "a part needs at least one pickable pose")
    if not sc.parts:
        ctx.add_problem("parts", "a scenario needs at least one part")
    th = sc.vision.threshold
    if th.block_px % 2 == 0:
        ctx.add_problem("vision.threshold.block_px", f"must be odd, got {th.block_px}")
    if th.method == "adaptive" and th.c >= 0:
        ctx.add_problem("vision.threshold.c",
                        f"must be < 0, got {_num(th.c)}: as in OpenCV the threshold is the "
                        f"local mean minus c, so c >= 0 makes flat belt foreground "
                        f"(c: -{_num(abs(th.c) or 5)} puts it {_num(abs(th.c) or 5)} grey "
                        f"levels above the mean)")
    _check_rulers(sc, ctx)
    for i, vc in enumerate(sc.vision.classes):
        cpath = f"vision.classes[{i}]"
        if vc.part not in sc.parts:
            ctx.add_problem(f"{cpath}.part", f"unknown part {vc.part!r}"
                                             f"{_suggest(vc.part, sc.parts)}; parts: "
                                             f"{', '.join(sc.parts)}")
            continue
        poses = sc.parts[vc.part].poses
        if vc.pose not in poses:
            ctx.add_problem(f"{cpath}.pose", f"part {vc.part!r} has no pose {vc.pose!r}"
                                             f"{_suggest(vc.pose, poses)}; poses: "
                                             f"{', '.join(poses)}")
    for name in sc.hopper:
        if name not in sc.parts:
            ctx.add_problem(f"hopper.parts.{name}", f"unknown part {name!r}"
                                                    f"{_suggest(name, sc.parts)}; parts: "
                                                    f"{', '.join(sc.parts)}",
                            line=ctx.key_lines.get(f"hopper.parts.{name}"))
    for i, name in enumerate(sc.retrieve.sequence):
        if name not in sc.parts:
            ctx.add_problem(f"retrieve.sequence[{i}]", f"unknown part {name!r}"
                                                       f"{_suggest(name, sc.parts)}")
    for name, n in sc.retrieve.kit.items():
        if name not in sc.parts:
            ctx.add_problem(f"retrieve.kit.{name}", f"unknown part {name!r}"
                                                    f"{_suggest(name, sc.parts)}")
        elif not isinstance(n, int) or isinstance(n, bool) or n < 1:
            ctx.add_problem(f"retrieve.kit.{name}", f"must be a whole number >= 1, got {n!r}")
    if sc.retrieve.kit and sc.retrieve.sequence:
        ctx.add_problem("retrieve.kit", "give a kit (any order) or a sequence (a kit in "
                                        "order), not both")
    if sc.retrieve.open_kits > 1 and not (sc.retrieve.kit or sc.retrieve.sequence):
        ctx.add_problem("retrieve.open_kits", "open kits need a retrieve.kit or a "
                                              "retrieve.sequence to build",
                        line=ctx.key_lines.get("retrieve.open_kits"))
    ctx.adjust_params = _check_adjust(sc.adjust, ctx)


def _check_rulers(sc: Scenario, ctx: _Ctx) -> None:
    """Each ruler is a line or a circle, named apart from the features; each class's ruler
    ranges name a ruler of the recipe and run low to high."""
    rulers = sc.vision.rulers
    for name, r in rulers.items():
        rpath = f"vision.rulers.{name}"
        if (r.line_deg is None) == (r.circle_mm is None):
            ctx.add_problem(rpath, "give exactly one of line_deg (a line through the "
                                   "centroid) and circle_mm (a circle about it)",
                            line=ctx.key_lines.get(rpath))
        if name in FEATURES:
            ctx.add_problem(rpath, f"{name!r} is a feature's name; name the ruler apart",
                            line=ctx.key_lines.get(rpath))
    for i, vc in enumerate(sc.vision.classes):
        for name, (lo, hi) in vc.rulers.items():
            path = f"vision.classes[{i}].rulers.{name}"
            if name not in rulers:
                ctx.add_problem(path, f"unknown ruler {name!r}{_suggest(name, rulers)}; "
                                      f"vision.rulers: {', '.join(rulers) or 'none'}",
                                line=ctx.key_lines.get(path))
            elif lo > hi:
                ctx.add_problem(path, f"range [lo, hi] has lo > hi: [{_num(lo)}, {_num(hi)}]")


def _check_adjust(adj: AdjustParams, ctx: _Ctx) -> dict[str, float]:
    """Check ``adjust.params`` against the tables, then let the adjuster check itself.

    Returns the parameters the adjuster will really use (its defaults filled in) so that
    speeds left at a default are still checked against the cell.
    """
    allowed = ADJUST_PARAMS[adj.algorithm]
    listed = len(ctx.problems)
    for key, v in adj.params.items():
        sub = f"adjust.params.{key}"
        if key not in allowed:
            if not allowed:
                ctx.add_problem(sub, f"algorithm {adj.algorithm!r} takes no params, got "
                                     f"{', '.join(map(repr, adj.params))}",
                                line=ctx.key_lines.get(sub))
                break
            ctx.note(ctx.unknown_error(key, "adjust.params", allowed,
                                       what=f"{adj.algorithm} parameter"))
            continue
        if not allowed[key].contains(v):
            ctx.add_problem(sub, f"must be {allowed[key].describe()}, got {_num(v)}")
    cls = ADJUSTERS.get(adj.algorithm)
    effective = dict(cls.PARAMS) if cls is not None else {}
    effective.update(adj.params)
    for algo, small, large, strict in ADJUST_ORDER:
        if algo != adj.algorithm or small not in effective or large not in effective:
            continue
        a, b = effective[small], effective[large]
        if a > b or (strict and a == b):
            given = "" if large in adj.params else " (its default)"
            ctx.add_problem(f"adjust.params.{small}",
                            f"must be {'<' if strict else '<='} {large} ({_num(b)}{given}), "
                            f"got {_num(a)}")
    if cls is not None and len(ctx.problems) == listed:   # not the same mistake twice
        try:
            effective = dict(cls(adj.params).params)
        except AdjusterParamError as e:
            what = str(e).removeprefix(f"{e.key}: ")
            ctx.add_problem(f"adjust.params.{e.key}", what)
    return effective


def _check_against_cell(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """Checks of the scenario against the cell it runs on (errors name the scenario line)."""
    hmax = cell.conveyors["horizontal"].max_mm_s
    imax = cell.conveyors["incline"].max_mm_s
    pct = sc.present.incline_pct
    cfile = str(cell.path)

    flagged: set[str] = set()

    def speed(path: str, v: float, note: str = "") -> None:
        if v > hmax or v * pct / 100.0 > imax:
            flagged.add(path)
        if v > hmax:
            ctx.add_problem(path, f"{_num(v)} mm/s{note} is above the horizontal conveyor's "
                                  f"max_mm_s {_num(hmax)} ({cfile})")
        elif v * pct / 100.0 > imax:
            ctx.add_problem(path, f"{_num(v)} mm/s{note} at incline_pct {_num(pct)} gives "
                                  f"{_num(v * pct / 100.0)} mm/s on the incline, above its "
                                  f"max_mm_s {_num(imax)} ({cfile})")

    h = sc.present.horizontal_mm_s
    if h > hmax:
        speed("present.horizontal_mm_s", h)
    elif h * pct / 100.0 > imax:
        ctx.add_problem("present.incline_pct", f"incline speed {_num(h)} * {_num(pct)}% = "
                                               f"{_num(h * pct / 100.0)} mm/s is above the "
                                               f"incline conveyor's max_mm_s {_num(imax)} "
                                               f"({cfile})")
    for key, v in ctx.adjust_params.items():   # with the adjuster's defaults filled in
        if key.endswith("_mm_s"):
            speed(f"adjust.params.{key}", v,
                  "" if key in sc.adjust.params else f" (the {sc.adjust.algorithm} default)")
    cls = ADJUSTERS.get(sc.adjust.algorithm)     # the adjuster's whole output range
    limits = {"horizontal": hmax, "incline": imax}
    try:
        envelope = cls(ctx.adjust_params).envelope(pct) if cls is not None else []
    except (AdjusterParamError, KeyError, TypeError, ValueError):
        envelope = []                            # its parameters were listed already
    for env in envelope:
        path = f"adjust.params.{env.key}"
        if env.mm_s > limits[env.conveyor] + 1e-9 and path not in flagged:
            flagged.add(path)
            given = "" if env.key in sc.adjust.params else f" (the {sc.adjust.algorithm} default)"
            ctx.add_problem(path, f"{env.how}{given} drives the {env.conveyor} conveyor at "
                            f"{_num(env.mm_s)} mm/s, above its max_mm_s "
                            f"{_num(limits[env.conveyor])} ({cfile}); an adjuster runs "
                            f"under the cell's limits, like a fixed setting")

    if not sc.parts:
        return                                # listed by _check_scenario
    for name, part in sc.parts.items():       # friction on the belt: a part's, or the cell's
        mus, muk = part.belt_friction(cell.sim)
        if 0 < mus < muk:
            ctx.add_problem(f"parts.{name}.belt_mu_kinetic",
                            f"{_num(muk)} is above its belt_mu_static {_num(mus)} (0 takes "
                            f"the cell's sim.belt_mu_*, {cfile}): sliding friction is never "
                            f"more than sticking friction")
    check_class_areas(sc, ctx, cell)
    check_class_rulers(sc, ctx, cell)
    _check_reach_and_kernels(sc, ctx, cell)
    window = cell.camera.height_px * cell.camera.calibration.mm_per_px
    biggest, size = max(((n, part_size_mm(p)) for n, p in sc.parts.items()),
                        key=lambda t: t[1])
    limit = window - size
    fs = sc.locate.frame_spacing_mm
    if fs >= limit:
        ctx.add_problem("locate.frame_spacing_mm",
                        f"must be < {_num(limit)} (camera window {_num(window)} mm along the "
                        f"belt minus the largest part, {biggest!r} {size:.1f} mm), got "
                        f"{_num(fs)}")


def _check_reach_and_kernels(sc: Scenario, ctx: _Ctx, cell: CellSpec) -> None:
    """What would only show in a run, as a silent zero or a frozen controller: a place pose
    the arm cannot reach, an opening wider than any part (it erases every one), and a
    closing wider than the image (OpenCV would allocate gigabytes for it)."""
    r = cell.robot
    bx, by = r.base_mm
    for name, part in sc.parts.items():
        d = math.hypot(part.place.x - bx, part.place.y - by)
        if not r.inner_reach_mm <= d <= r.reach_mm:
            ctx.add_problem(f"parts.{name}.place",
                            f"({_num(part.place.x)}, {_num(part.place.y)}) is {_num(round(d, 1))} "
                            f"mm from the robot base {_num(bx)}, {_num(by)}: outside its reach "
                            f"{_num(r.inner_reach_mm)}-{_num(r.reach_mm)} mm ({cell.path})")
    m = sc.vision.morphology
    cam = cell.camera
    widest = max(part_size_mm(p) for p in sc.parts.values()) / cam.calibration.mm_per_px
    if m.open_px >= widest:
        ctx.add_problem("vision.morphology.open_px",
                        f"must be < {math.ceil(widest)} px: an opening {m.open_px} px wide "
                        f"erases every part (the largest is {widest:.0f} px across at "
                        f"{_num(cam.calibration.mm_per_px)} mm/px)")
    side = min(cam.width_px, cam.height_px)
    if m.close_px >= side:
        ctx.add_problem("vision.morphology.close_px",
                        f"must be < {side} px, the image's shorter side ({cam.width_px} x "
                        f"{cam.height_px} px), got {m.close_px}")
