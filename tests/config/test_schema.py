"""``feeder schema``: the JSON Schemas an editor checks YAML with, validated with an
off-the-shelf validator (jsonschema). Every shipped file passes; a misspelt key fails; and
the schema never refuses what the loader takes (an editor must not flag a good file)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import jsonschema
import pytest
import yaml

from feeder_bt.cli.main import main
from feeder_bt.config.files import load_fault_plan
from feeder_bt.config.loader import load_cell, load_scenario
from feeder_bt.config.schema import KINDS, file_kind, schema
from feeder_bt.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = {
    "scenario": sorted((ROOT / "scenarios").glob("*.yaml")) + [ROOT / "examples/gussets.yaml",
                                                          ROOT / "examples/sprockets.yaml"],
    "cell": sorted((ROOT / "cells").glob("*.yaml")),
    "faults": sorted((ROOT / "faults").glob("*.yaml")),
}
LOADERS = {"scenario": load_scenario, "cell": load_cell, "faults": load_fault_plan}


def validator(kind: str):
    s = schema(kind)
    jsonschema.Draft7Validator.check_schema(s)
    return jsonschema.Draft7Validator(s)


def test_the_command_prints_each_schema(capsys, tmp_path):
    for kind in KINDS:
        assert main(["schema", kind]) == 0
        printed = json.loads(capsys.readouterr().out)
        assert printed == schema(kind) and printed["additionalProperties"] is False
    out = tmp_path / "scenario.json"
    assert main(["schema", "scenario", "-o", str(out)]) == 0
    assert json.loads(out.read_text())["title"] == "feeder_bt scenario"


@pytest.mark.parametrize("kind,path", [(k, p) for k, ps in SHIPPED.items() for p in ps],
                         ids=lambda v: v.name if isinstance(v, Path) else v)
def test_every_shipped_file_is_valid_and_of_its_kind(kind, path):
    errors = list(validator(kind).iter_errors(yaml.safe_load(path.read_text())))
    assert errors == [], [e.message for e in errors]
    assert file_kind(path) == kind


@pytest.mark.parametrize("kind,path,where,bad", [
    ("scenario", "scenarios/lenses.yaml", ("present",), "horizontal_mm_sec"),
    ("scenario", "scenarios/lenses.yaml", (), "tick_hzz"),
    ("scenario", "scenarios/squares.yaml", ("vision", "classes", 0), "aera_mm2"),
    ("scenario", "scenarios/lenses.yaml", ("parts", "lens", "poses", "flat"), "pickabel"),
    ("scenario", "scenarios/lenses.yaml", ("adjust", "params"), "hihg"),
    ("cell", "cells/sim.yaml", ("camera",), "calibraton_file"),
    ("cell", "cells/sim.yaml", ("conveyors", "horizontal"), "max_mm_sec"),
    ("faults", "faults/shift.yaml", ("rates",), "servo_timout"),
    ("faults", "faults/shift.yaml", ("scripted", 0), "release_after"),
])
def test_a_misspelt_key_is_rejected_by_the_schema_and_the_loader(kind, path, where, bad,
                                                                  tmp_path):
    data = yaml.safe_load((ROOT / path).read_text())
    node = data
    for step in where:
        node = node.setdefault(step, {}) if isinstance(step, str) else node[step]
    node[bad] = 1
    errors = list(validator(kind).iter_errors(data))
    assert errors and any(bad in e.message for e in errors), [e.message for e in errors]
    with pytest.raises(ConfigError, match=bad):
        LOADERS[kind](_write(tmp_path, kind, data))


def _write(tmp_path: Path, kind: str, data: dict) -> Path:
    if kind == "scenario":
        data = {**data, "cell": str((ROOT / "scenarios" / data["cell"]).resolve())}
    p = tmp_path / f"{kind}.yaml"
    p.write_text(yaml.safe_dump(data, sort_keys=False))
    return p


def _mutations(data, path=()):
    """Copies of ``data`` with one thing wrong: a key misspelt, a number out of any sane
    range, a string that names nothing."""
    if isinstance(data, dict):
        for key, value in data.items():
            yield path + (key,), ("key", key + "_x")
            yield from _mutations(value, path + (key,))
    elif isinstance(data, list):
        for i, value in enumerate(data):
            yield from _mutations(value, path + (i,))
    elif isinstance(data, bool):
        yield path, ("value", "yes please")
    elif isinstance(data, int | float):
        yield path, ("value", -1)
        yield path, ("value", 10**7)
    elif isinstance(data, str):
        yield path, ("value", "zzz")


def _apply(data, path, change):
    data = copy.deepcopy(data)
    node = data
    for step in path[:-1]:
        node = node[step]
    what, new = change
    if what == "key":
        node[new] = node.pop(path[-1])
    else:
        node[path[-1]] = new
    return data


@pytest.mark.parametrize("kind,path", [("scenario", "scenarios/lenses.yaml"),
                                       ("scenario", "scenarios/squares.yaml"),
                                       ("scenario", "examples/sprockets.yaml"),
                                       ("cell", "cells/sim.yaml"),
                                       ("faults", "faults/shift.yaml")])
def test_the_schema_never_refuses_what_the_loader_takes(kind, path, tmp_path):
    """One mistake at a time in every place of a shipped file: whenever the loader takes
    the file, so does the schema; and a misspelt key of the loader's own is refused by
    both (keys that are names, such as a part's, are free in both)."""
    data = yaml.safe_load((ROOT / path).read_text())
    v = validator(kind)
    refused_keys = 0
    for where, change in _mutations(data):
        if kind == "scenario" and where == ("cell",):
            continue                      # the cell file is another file's business
        bad = _apply(data, where, change)
        schema_ok = v.is_valid(bad)
        try:
            LOADERS[kind](_write(tmp_path, kind, bad))
            loader_ok = True
        except ConfigError:
            loader_ok = False
        assert schema_ok or not loader_ok, (where, change, [e.message for e in
                                                            v.iter_errors(bad)])
        if change[0] == "key" and not schema_ok:
            refused_keys += 1
            assert not loader_ok, (where, change)
    assert refused_keys >= 10


def test_check_lists_every_problem_of_a_file(tmp_path, capsys):
    """The loader lists every problem of a file, each on its line, in file order."""
    text = (ROOT / "scenarios/lenses.yaml").read_text()
    for old, new in [("tick_hz: 200", "tick_hzz: 200"),
                     ("method: fixed, value: 80", "method: fixd, value: 800"),
                     ("horizontal_mm_s: 150", "horizontal_mm_s: fast"),
                     ("size_mm: [50.8, 14.0]", "size_mm: [50.8, 14.0, 3]")]:
        assert old in text
        text = text.replace(old, new)
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("cell: ../cells/sim.yaml",
                                f"cell: {ROOT / 'cells' / 'sim.yaml'}"))
    lines = text.splitlines()

    def line_of(needle: str) -> int:
        return next(i for i, s in enumerate(lines, 1) if needle in s)

    assert main(["check", str(bad)]) == 2
    captured = capsys.readouterr()
    assert captured.out == "5 problems in 1 of 1 file\n"
    err = captured.err.strip().splitlines()
    assert err[0].endswith("(read as a scenario)")
    want = [
        (line_of("tick_hzz"), "tick_hzz: unknown key 'tick_hzz' (did you mean 'tick_hz'?)"),
        (line_of("size_mm"), "size_mm: expected a list of 2 values, got 3"),
        (line_of("fixd"), "vision.threshold.method: must be one of fixed, otsu, adaptive, "
                          "got 'fixd' (did you mean 'fixed'?)"),
        (line_of("fixd"), "vision.threshold.value: must be in [0, 255], got 800"),
        (line_of("horizontal_mm_s"), "present.horizontal_mm_s: expected a number, got "
                                     "string 'fast'"),
    ]
    assert len(err) == len(want), err
    for got, (line, what) in zip(err, want, strict=True):
        assert got.startswith(f"{bad}:{line}: ") and what in got, (got, line, what)


@pytest.mark.parametrize("where,key,bad,said", [
    (("vision", "outline_match"), "min_iou", 1.5, "min_iou"),
    (("vision", "outline_match"), "raster_mm", 0.0, "raster_mm"),
    (("vision", "classes", 0), "orientation", "outlines", "orientation"),
])
def test_outline_thresholds_and_class_orientations_are_checked_both_ways(where, key, bad, said,
                                                                          tmp_path):
    """``outline_match`` out of its ranges, a class orientation not among the recipe's:
    the editor's schema and the loader both refuse them."""
    data = yaml.safe_load((ROOT / "scenarios/levers.yaml").read_text())
    node = data
    for step in where:
        node = node[step]
    node[key] = bad
    assert list(validator("scenario").iter_errors(data))
    with pytest.raises(ConfigError, match=said):
        load_scenario(_write(tmp_path, "scenario", data))
