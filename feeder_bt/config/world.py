"""World files: the simulated cell's truth, apart from the cell file the controller reads.

``feeder run SCENARIO --world PLANT.yaml``: the cell file (and the scenario) stay what the
controller believes; the world file says how the simulated cell really is. It holds any
physical figure of a cell file (conveyors, the return transit, the hopper, the robot's
figures, the camera's timing and rendering) and every ``sim:`` figure, laid over the cell
file key by key, so a figure it leaves out is the cell file's. Without a world file the
cell file's figures serve both, as before.

What the controller alone owns — its name, HAL, wiring, controllers, the camera's
calibration, the robot's frame — is not a world figure: a world file that names one is
refused, so a world can never change what the controller believes.

A world file may carry ``fit:``, a twin's notes (each figure's estimate, uncertainty and
what in the log fixed it: ``feeder twin fit``); the simulator does not read it.

Validation is the cell file's own (the walker and the cross-key checks), with every
problem of a key the world file gave reported at the world file's line.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from yaml.nodes import MappingNode, ScalarNode

from feeder_bt.config.checks import _check_cell
from feeder_bt.config.loader import _compose
from feeder_bt.config.overlay import _from_overlay, _merge, blame_overlay
from feeder_bt.config.walker import _Ctx, _suggest
from feeder_bt.core.errors import ConfigError
from feeder_bt.core.model import CellSpec

#: top-level keys of a world file, and within each the keys that are not world figures
WORLD_SECTIONS: dict[str, frozenset[str]] = {
    "conveyors": frozenset(),
    "hopper": frozenset(),
    "encoder": frozenset({"conveyor_bits", "robot_bits", "robot_start"}),
    "camera": frozenset({"calibration", "calibration_file", "source", "pylon", "target",
                         "width_px", "height_px"}),
    "robot": frozenset({"model", "frame_file", "touch_points_mm", "safe_mm"}),
    "sim": frozenset(),
    "plate": frozenset({"url", "baud", "timeout_s", "quiet_s", "echo_probe_s", "commands",
                        "speeds", "repetitions"}),
}
#: a twin's notes: read by people and by ``feeder twin``, never by the simulator
NOTES_KEY = "fit"


def _key(node: Any) -> str | None:
    return node.value if isinstance(node, ScalarNode) else None


def _only_world_figures(root: MappingNode, file: str) -> MappingNode:
    """``root`` without its notes; every key that is not a world figure is a problem."""
    problems: list[ConfigError] = []
    kept = []
    for knode, vnode in root.value:
        key = _key(knode)
        line = knode.start_mark.line + 1
        if key == NOTES_KEY:
            continue
        if key not in WORLD_SECTIONS:
            problems.append(ConfigError(
                f"not a world figure{_suggest(str(key), (*WORLD_SECTIONS, NOTES_KEY))}; a world "
                f"file holds {', '.join(WORLD_SECTIONS)} (and {NOTES_KEY}: notes)",
                file=file, line=line, key=str(key)))
            continue
        if isinstance(vnode, MappingNode):
            for k2, _ in vnode.value:
                sub = _key(k2)
                if sub in WORLD_SECTIONS[key]:
                    problems.append(ConfigError(
                        "is the controller's belief, not a world figure: set it in the "
                        "cell file", file=file, line=k2.start_mark.line + 1,
                        key=f"{key}.{sub}"))
        kept.append((knode, vnode))
    if problems:
        raise ConfigError.of(problems)
    return MappingNode(root.tag, kept, root.start_mark, root.end_mark, root.flow_style)


def world_notes(path: str | Path) -> dict[str, Any]:
    """A world file's ``fit:`` notes as plain data (empty when it has none)."""
    import yaml

    from feeder_bt.config.loader import read_yaml_text
    data = yaml.safe_load(read_yaml_text(Path(path), str(path))) or {}
    notes = data.get(NOTES_KEY) if isinstance(data, dict) else None
    return notes if isinstance(notes, dict) else {}


def load_world(path: str | Path, cell: CellSpec) -> CellSpec:
    """The simulated cell's truth: ``cell`` (what the controller believes, as loaded from
    its file) with the world file's figures laid over it, validated as a cell file is.

    The camera's calibration and the robot's frame stay the cell's (the world's camera is
    placed by ``sim_truth`` and the ``sim.calib_*`` figures)."""
    import dataclasses

    world, taken = _laid_over(path, _compose(Path(cell.path), _Ctx(str(cell.path))),
                              str(cell.path), cell.path)
    return dataclasses.replace(
        world,
        camera=dataclasses.replace(world.camera, calibration=cell.camera.calibration),
        robot=dataclasses.replace(world.robot, base_mm=world.robot.base_mm
                                  if _from_overlay("robot.base_mm", taken) else cell.robot.base_mm,
                                  base_deg=world.robot.base_deg
                                  if _from_overlay("robot.base_deg", taken)
                                  else cell.robot.base_deg))


def looks_like_world(path: str | Path) -> bool:
    """Whether a file's top-level keys are all a world file's (``feeder check`` reads it as
    one rather than as a cell file missing its name)."""
    try:
        root = _compose(Path(path), _Ctx(str(path)))
    except ConfigError:
        return False
    keys = {_key(k) for k, _ in root.value}
    return bool(keys) and keys <= {*WORLD_SECTIONS, NOTES_KEY}


def check_world(path: str | Path) -> None:
    """Validate a world file on its own (``feeder check``): over an empty cell, so every
    key and value is judged as in any cell file (ConfigError: every problem)."""
    import yaml
    empty = yaml.compose("name: world\n", Loader=yaml.SafeLoader)
    _laid_over(path, empty, str(path), Path(path))


def _laid_over(path: str | Path, base: MappingNode, base_file: str, cell_path: Path
               ) -> tuple[CellSpec, set[str]]:
    """The world file at ``path`` merged over the cell file's root node ``base`` and
    validated: the cell and the keys the world gave (their problems at the world's lines)."""
    wpath = Path(path)
    wfile = str(wpath)
    wroot = _compose(wpath, _Ctx(wfile))
    from feeder_bt.config.schema import check_kind
    check_kind(wroot, "world", wpath)
    wroot = _only_world_figures(wroot, wfile)
    ctx = _Ctx(base_file)
    taken: set[str] = set()
    merged = _merge(base, wroot, "", taken)
    blame_overlay(ctx, taken, wfile)
    world = ctx.collect(ctx.dataclass, CellSpec, merged, "", fill={"path": cell_path})
    if world is not None:
        ctx.collect(_check_cell, world, ctx)
    ctx.raise_problems()
    return world, taken


def world_schema() -> dict[str, Any]:
    """The JSON Schema of a world file (``feeder schema world``): the cell file's, kept to
    the world's sections and figures, nothing required, and the ``fit:`` notes."""
    from feeder_bt.config.schema import schema
    cell = schema("cell")
    props: dict[str, Any] = {}
    for key, beliefs in WORLD_SECTIONS.items():
        sec = cell["properties"].get(key)
        if sec is None:
            continue
        sec = dict(sec)
        if "properties" in sec:
            sec["properties"] = {k: v for k, v in sec["properties"].items() if k not in beliefs}
            sec.pop("required", None)
        props[key] = sec
    props[NOTES_KEY] = {"type": "object", "description": "a twin's notes (feeder twin fit): "
                        "each figure's estimate, uncertainty and what fixed it; not read by "
                        "the simulator"}
    return {"$schema": cell["$schema"], "$id": "urn:feeder-bt:schema:world",
            "title": "feeder_bt world", "description": "a world file for feeder_bt: the "
            "simulated cell's truth, laid over the cell file (feeder run --world)",
            "type": "object", "properties": props, "additionalProperties": False}

