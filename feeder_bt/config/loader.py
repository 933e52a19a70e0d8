"""Load and validate scenario, cell and fault-plan YAML files into the dataclasses of
``model.py`` and ``faults.py``: the public entry points.

Every problem is reported as one line ``FILE:LINE: dotted.key: what is wrong`` instead of
a traceback far from the cause, and every problem of a file is listed, not only the first:
one ``ConfigError`` (``ConfigProblems`` when there are several) in file order. A problem
that makes the rest meaningless (a file that is not YAML) stops early. The work is split by
concept:

- this module: reading a file (``_compose``) and the entry points ``load_*``, ``check_*``;
- ``walker.py``: the generic node walker (``_Ctx``) that follows the dataclass fields and
  type hints of the model, and gathers the problems of each key and item;
- ``special.py``: where the YAML is not a mirror of the model (``Shape``, ``VisionClass``,
  ``Scenario.hopper``, ``CellSpec.conveyors``);
- ``tables.py``: the tables of allowed values (enumerations, numeric ranges, adjuster
  parameters), reused by the CLI, the JSON Schemas, docs and adjusters;
- ``checks.py``: checks across keys, and of a scenario against its cell.

This module re-exports the names other modules use, so ``feeder_bt.config.loader``
stays the one place to import from.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import yaml
from yaml.nodes import MappingNode, ScalarNode

from feeder_bt.config.checks import (  # noqa: F401 - re-exported
    GALIL_MAX_INPUT,
    GALIL_MAX_OUTPUT,
    _check_adjust,
    _check_against_cell,
    _check_cell,
    _check_galil,
    _check_scenario,
)
from feeder_bt.config.special import part_size_mm
from feeder_bt.config.tables import (  # noqa: F401 - re-exported
    _EXTRA_KEYS,
    _IMPLIED_FIELDS,
    ADJUST_ALGORITHMS,
    ADJUST_ORDER,
    ADJUST_PARAMS,
    CELL_HALS,
    CONVEYOR_NAMES,
    ENUMS,
    FOREGROUNDS,
    GREY,
    IO_DIRS,
    LEAF_RE,
    LIGHTINGS,
    NON_NEGATIVE,
    ORIENTATION_METHODS,
    POSITIVE,
    PRESENT_MODES,
    PROBABILITY_TOLERANCE,
    RANGES,
    RETRIEVE_POLICIES,
    SHAPE_KINDS,
    SHAPE_OPTIONAL,
    TARGET_KINDS,
    THRESHOLD_METHODS,
    Range,
    _num,
)
from feeder_bt.config.walker import (  # noqa: F401 - re-exported
    _FIELD_BUILDERS,
    _SPECIAL_TYPES,
    _Ctx,
    _describe,
    _hints,
    _join,
    _one_line,
    _optional_of,
    _parent,
    _required,
    _short,
    _suggest,
)
from feeder_bt.core.didyoumean import hint
from feeder_bt.core.errors import ConfigError
from feeder_bt.core.model import (  # noqa: F401 - re-exported
    AdjustParams,
    CellSpec,
    Scenario,
)
from feeder_bt.vision.features import FEATURES  # noqa: F401 - re-exported

__all__ = [
    "ADJUST_ALGORITHMS", "ADJUST_ORDER", "ADJUST_PARAMS", "CELL_HALS", "CONVEYOR_NAMES",
    "ENUMS", "FOREGROUNDS", "IO_DIRS", "LEAF_RE", "ORIENTATION_METHODS", "PRESENT_MODES",
    "PROBABILITY_TOLERANCE", "RANGES", "RETRIEVE_POLICIES", "SHAPE_KINDS", "THRESHOLD_METHODS",
    "Range", "load_cell",
    "load_scenario", "part_size_mm",
]


# ============================================================================ files

MAX_FILE_BYTES = 2**20        # the largest shipped file is ~20 kB; 50 MB took 42 s to check


def read_yaml_text(path: Path, file: str) -> str:
    """A YAML file's text; every failure is a one-line ConfigError. Only a regular file is
    read (a FIFO would block ``feeder check``), and at most ``MAX_FILE_BYTES`` of it: a
    scenario, a cell or a plan is a few kB."""
    try:
        st = path.stat()
        if stat.S_ISREG(st.st_mode) and st.st_size > MAX_FILE_BYTES:
            raise ConfigError(f"is {st.st_size / 2**20:.1f} MiB; a YAML file here is a few kB "
                              f"(at most {MAX_FILE_BYTES // 2**20} MiB is read)", file=file)
        if not stat.S_ISREG(st.st_mode) and not stat.S_ISDIR(st.st_mode):
            raise ConfigError("is not a regular file (a FIFO, socket or device); expected a "
                              "YAML file", file=file)
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"file not found{hint(path)}", file=file) from None
    except IsADirectoryError:
        raise ConfigError("is a directory, not a YAML file", file=file) from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"not UTF-8 text ({e.reason} at byte {e.start})", file=file) from None
    except OSError as e:
        raise ConfigError(f"cannot read: {e.strerror or e}", file=file) from None


def _compose(path: Path, ctx: _Ctx) -> MappingNode:
    """Read and parse one file into its root mapping node; every failure is a ConfigError."""
    text = read_yaml_text(path, ctx.file)
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        what = e.problem or e.context or "syntax error"
        if e.context and e.problem and e.context_mark is not None:
            what += f" ({e.context} at line {e.context_mark.line + 1})"
        raise ConfigError(_one_line(f"YAML syntax error: {what}"), file=ctx.file,
                          line=mark.line + 1 if mark else None) from None
    except yaml.reader.ReaderError as e:
        line = text[: e.position].count("\n") + 1 if isinstance(e.position, int) else None
        raise ConfigError(f"unacceptable character #x{e.character:04x} in the file",
                          file=ctx.file, line=line) from None
    except yaml.YAMLError as e:
        raise ConfigError(_one_line(f"YAML error: {e}"), file=ctx.file) from None
    except RecursionError:
        raise ConfigError("YAML nested too deeply", file=ctx.file) from None
    if root is None:
        raise ConfigError("file is empty; expected a mapping of keys", file=ctx.file, line=1)
    if not isinstance(root, MappingNode):
        v = root if not isinstance(root, ScalarNode) else ctx.scalar(root, "")
        raise ConfigError(f"expected a mapping of keys at the top, got {_describe(v)}",
                          file=ctx.file, line=root.start_mark.line + 1)
    ctx.lines[""] = root.start_mark.line + 1
    return root


def _check_kind(root: MappingNode, kind: str, path: Path) -> None:
    """A file of another kind (a cell description given as a scenario, say) is one line
    saying what it is, not a line for each key (``schema.wrong_kind``)."""
    from feeder_bt.config.schema import check_kind
    check_kind(root, kind, path)


def _load_cell(path: Path, calibration_files: bool = True) -> tuple[CellSpec, _Ctx]:
    ctx = _Ctx(str(path))
    root = _compose(path, ctx)
    _check_kind(root, "cell", path)
    cell = ctx.collect(ctx.dataclass, CellSpec, root, "", fill={"path": path})
    if cell is not None:
        ctx.collect(_check_cell, cell, ctx)
    ctx.raise_problems()
    if calibration_files:
        from feeder_bt.calibration.files import apply_calibration_file, apply_robot_frame_file
        cell = apply_calibration_file(cell, line=ctx.line("camera.calibration_file"))
        cell = apply_robot_frame_file(cell, line=ctx.line("robot.frame_file"))
    return cell, ctx


def load_cell(path: str | Path, calibration_files: bool = True) -> CellSpec:
    """Load and validate a cell description (the hardware a scenario runs on).

    ``calibration_files=False`` leaves out the calibration files the cell names: the
    calibration commands load the cell before they write those files."""
    return _load_cell(Path(path), calibration_files)[0]


def load_scenario(path: str | Path, cell: str | Path | None = None,
                  overlay: str | Path | None = None) -> tuple[Scenario, CellSpec]:
    """Load a scenario and its cell, validated against each other.

    The scenario's ``cell:`` key is relative to the scenario file; ``cell`` overrides it so
    one scenario runs unchanged on the simulated cell, emulators or a real cell. Every
    problem of the scenario, then of its cell, is raised at once; the checks against the
    cell run when both files are whole. An ``overlay`` file is merged over the scenario
    before validation (scenario/overlay.py).
    """
    path = Path(path)
    ctx = _Ctx(str(path))
    root = _compose(path, ctx)
    _check_kind(root, "scenario", path)
    if overlay is not None:
        from feeder_bt.config.overlay import apply_overlay
        root = apply_overlay(root, overlay, ctx, _compose, _Ctx)
    cell_path = ctx.collect(_cell_path, path, root, ctx, cell)
    scenario = ctx.collect(ctx.dataclass, Scenario, root, "",
                           fill={"path": path, "cell_path": cell_path or Path(),
                                 "overlay_path": Path(overlay) if overlay else None})
    if scenario is not None:
        ctx.collect(_check_scenario, scenario, ctx)
    cell_spec, cell_problems = None, []
    if cell_path is not None:
        try:
            cell_spec, _ = _load_cell(cell_path)
        except ConfigError as e:      # listed after the scenario's own
            cell_problems = e.problems
    if scenario is not None and cell_spec is not None:
        ctx.collect(_check_against_cell, scenario, ctx, cell_spec)
    ctx.raise_problems(more=cell_problems)
    return scenario, cell_spec


def _cell_path(path: Path, root: MappingNode, ctx: _Ctx, cell: str | Path | None) -> Path:
    """The cell file a scenario runs on: ``cell`` when given, else its ``cell:`` key."""
    cell_node = next((v for k, _, v in ctx.entries(root, "") if k == "cell"), None)
    if cell is not None:
        cell_path = Path(cell)
        if cell_node is not None:
            ctx.build(str, cell_node, "cell")
    elif cell_node is None:
        raise ctx.error("cell", "missing required key 'cell' (the cell description file, "
                                "relative to this scenario)", line=root.start_mark.line + 1)
    else:
        rel = ctx.build(str, cell_node, "cell")
        if not rel.strip():
            raise ctx.error("cell", "must name a cell file, got an empty string")
        cell_path = Path(os.path.normpath(path.parent / rel))
        if not cell_path.is_file():
            what = "is not a file" if cell_path.exists() else "not found"
            raise ctx.error("cell", f"cell file {rel!r} {what} (looked for {cell_path})")
    return cell_path
