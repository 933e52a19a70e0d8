"""Fault plan files: the shipped plan loads; every bad plan is one FILE:LINE: key: what line."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from feeder_bt.config.faults import (
    FAULT_KINDS,
    RATE_UNITS,
    FaultPlanSpec,
    FaultRate,
    ScriptedFault,
)
from feeder_bt.config.files import LOADERS, load_fault_plan
from feeder_bt.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[2]
SHIFT = ROOT / "faults" / "shift.yaml"

GOOD = """\
seed: 4
rates:
  servo_timeout: {per_pick: 0.005}
  comms_lost:
    per_hour: 2
    device: alternate
    outage_s: 3.5
  grab_failed: {per_frame: 0.002}
  conveyor_jam: {per_hour: 0.5}
  missed_grab: {per_pick: 0.01}
  encoder_slip: {per_hour: 0.1, counts: 40}
scripted:
  - {at_s: 7200, kind: estop, release_after_s: 60}
  - {at_s: 100, kind: comms_lost, device: camera, outage_s: 1}
  - {at_s: 50, kind: conveyor_jam}
"""


def write(tmp_path: Path, text: str, name: str = "plan.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def expect(path: Path, line: int | None, key: str | None, *fragments: str) -> ConfigError:
    """One ConfigError on one line naming the file, the line and the key."""
    with pytest.raises(ConfigError) as info:
        load_fault_plan(path)
    e = info.value
    msg = str(e)
    assert "\n" not in msg, msg
    assert e.file == str(path), msg
    assert e.line == line, msg
    assert e.key == key, msg
    assert msg.startswith(f"{path}:{line}: " if line else f"{path}: "), msg
    for f in fragments:
        assert f in msg, msg
    return e


def test_shipped_shift_plan_matches_the_issue():
    plan = load_fault_plan(SHIFT)
    assert plan.path == SHIFT
    assert plan.rates["servo_timeout"].rate() == ("per_pick", pytest.approx(1 / 200))
    comms = plan.rates["comms_lost"]
    assert comms.rate() == ("per_hour", 2.0) and comms.device == "alternate"
    assert plan.rates["grab_failed"].rate() == ("per_frame", pytest.approx(1 / 500))
    estops = [s for s in plan.scripted if s.kind == "estop"]
    assert [s.at_s for s in estops] == [7200.0, 21600.0]
    assert all(s.release_after_s == 60.0 for s in estops)
    assert LOADERS["faults"](SHIFT) == plan        # feeder check's entry point


def test_good_plan_loads_with_defaults(tmp_path):
    plan = load_fault_plan(write(tmp_path, GOOD))
    assert isinstance(plan, FaultPlanSpec) and plan.seed == 4
    assert set(plan.rates) == set(RATE_UNITS)
    assert plan.rates["comms_lost"] == FaultRate(per_hour=2.0, device="alternate", outage_s=3.5)
    assert plan.rates["conveyor_jam"].outage_s == 2.0          # the default
    assert plan.scripted[0] == ScriptedFault(at_s=7200.0, kind="estop", release_after_s=60.0)
    assert plan.scripted[1].device == "camera" and plan.scripted[1].outage_s == 1.0
    assert plan.scripted[2].release_after_s == 30.0            # the default


def test_minimal_plans(tmp_path):
    assert load_fault_plan(write(tmp_path, "seed: 0\n")) == FaultPlanSpec(
        path=tmp_path / "plan.yaml")
    plan = load_fault_plan(write(tmp_path, "scripted: [{at_s: 0, kind: estop}]\n"))
    assert plan.rates == {} and plan.scripted[0].release_after_s == 30.0


# (text, line, key, fragments): each one mistake in a plan.
BAD = [
    ("rats: {}\n", 1, "rats", "unknown key 'rats'", "did you mean 'rates'"),
    ("seed: 1.5\n", 1, "seed", "expected an integer"),
    ("seed: 1\nseed: 2\n", 2, "seed", "duplicate key"),
    ("rates:\n  servo_timout: {per_pick: 0.1}\n", 2, "rates.servo_timout",
     "unknown fault kind", "did you mean 'servo_timeout'"),
    ("rates:\n  servo_timeout: {per_pick: 1.5}\n", 2, "rates.servo_timeout.per_pick",
     "must be in [0, 1], got 1.5"),
    ("rates:\n  grab_failed: {per_frame: -0.1}\n", 2, "rates.grab_failed.per_frame",
     "must be in [0, 1]"),
    ("rates:\n  comms_lost: {per_hour: -2}\n", 2, "rates.comms_lost.per_hour", "must be >= 0"),
    ("rates:\n  servo_timeout:\n    per_frame: 0.1\n", 3, "rates.servo_timeout.per_frame",
     "servo_timeout takes per_pick, not per_frame"),
    ("rates:\n  grab_failed: {per_frame: 0.1, per_pick: 0.1}\n", 2,
     "rates.grab_failed.per_pick", "grab_failed takes per_frame, not per_pick"),
    ("rates:\n  comms_lost: {per_pick: 0.1}\n", 2, "rates.comms_lost.per_pick",
     "takes per_hour"),
    ("rates:\n  conveyor_jam: {device: galil}\n", 2, "rates.conveyor_jam",
     "missing required key 'per_hour'"),
    ("rates:\n  comms_lost: {per_hour: 1, device: robot}\n", 2, "rates.comms_lost.device",
     "must be one of galil, adept, camera, plate, alternate", "'robot'"),
    ("rates:\n  comms_lost: {per_hour: 1, outage_s: 0}\n", 2, "rates.comms_lost.outage_s",
     "must be > 0"),
    ("rates:\n  grab_failed:\n    per_frame: 0.1\n    outage_s: 3\n", 4,
     "rates.grab_failed.outage_s", "applies only to comms_lost"),
    ("rates:\n  estop: {per_hour: 1}\n", 2, "rates.estop", "scripted only"),
    ("rates:\n  servo_timeout: {per_pick: 0.1, per_pik: 1}\n", 2,
     "rates.servo_timeout.per_pik", "did you mean 'per_pick'"),
    ("rates:\n  servo_timeout: {per_pick: lots}\n", 2, "rates.servo_timeout.per_pick",
     "expected a number"),
    ("rates: [servo_timeout]\n", 1, "rates", "expected a mapping"),
    ("scripted:\n  - {at_s: 5, kind: estopp}\n", 2, "scripted[0].kind",
     "must be one of", "did you mean 'estop'"),
    ("scripted:\n  - {kind: estop}\n", 2, "scripted[0].at_s", "missing required key 'at_s'"),
    ("scripted:\n  - {at_s: -1, kind: estop}\n", 2, "scripted[0].at_s", "must be >= 0"),
    ("scripted:\n  - {at_s: 1, kind: estop, release_after_s: 0}\n", 2,
     "scripted[0].release_after_s", "must be > 0"),
    ("scripted:\n  - at_s: 1\n    kind: comms_lost\n    release_after_s: 5\n", 4,
     "scripted[0].release_after_s", "applies only to estop, not comms_lost"),
    ("scripted:\n  - {at_s: 1, kind: estop, device: galil}\n", 2, "scripted[0].device",
     "applies only to comms_lost"),
    ("scripted:\n  - {at_s: 1, kind: comms_lost, device: plc}\n", 2, "scripted[0].device",
     "must be one of"),
    ("scripted: {at_s: 1}\n", 1, "scripted", "expected a list"),
    ("scripted:\n  - [1, estop]\n", 2, "scripted[0]", "expected a mapping"),
    ("seed: [1\n", 2, None, "YAML syntax error"),
    ("- 1\n", 1, None, "expected a mapping of keys at the top"),
    ("", 1, None, "file is empty"),
]


@pytest.mark.parametrize("text,line,key,fragments", [(t, ln, k, f) for t, ln, k, *f in BAD],
                         ids=[f"bad{i}" for i in range(len(BAD))])
def test_bad_plans_give_one_line(tmp_path, text, line, key, fragments):
    expect(write(tmp_path, text), line, key, *fragments)


def test_missing_file(tmp_path):
    expect(tmp_path / "nope.yaml", None, None, "file not found")


def test_every_kind_is_described_in_the_docs():
    doc = (ROOT / "docs" / "faults.md").read_text()
    for kind in FAULT_KINDS:
        assert f"`{kind}`" in doc, kind


# ---------------------------------------------------------------------------- fuzz

KEYS = ["seed", "rates", "scripted", "at_s", "kind", "release_after_s", "device", "outage_s",
        *FAULT_KINDS, "per_pick", "per_frame", "per_hour", "sede", "x"]
scalars = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20),
                    st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from(KEYS + ["alternate", "galil", "adept", "camera"]),
                    st.text(max_size=12))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4),
    st.dictionaries(st.one_of(st.sampled_from(KEYS), scalars), inner, max_size=4)),
    max_leaves=20)
plans = st.dictionaries(st.sampled_from(KEYS), values, max_size=4)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz")


def _load_or_config_error(path: Path) -> None:
    try:
        plan = load_fault_plan(path)
    except ConfigError as e:
        for problem in e.problems:            # every problem is one line naming the file
            msg = str(problem)
            assert msg and "\n" not in msg and "\r" not in msg, msg
            assert msg.startswith(str(path)), msg
    else:
        assert isinstance(plan, FaultPlanSpec)


@settings(max_examples=150, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(plans)
def test_fuzz_structures_load_or_config_error(fuzz_dir, data):
    p = fuzz_dir / "structure.yaml"
    p.write_text(yaml.safe_dump(data, allow_unicode=True), encoding="utf-8")
    _load_or_config_error(p)


TOKENS = [*"ab:-[]{},#&*!|>'\"%@`? \n\t.0123456789e_", "seed", "rates", "scripted",
          "per_pick", "kind", "estop", "at_s", "\n  ", "\n  - ", "<<: ", "!!float ", "\x00",
          "\u00e9"]
YAMLISH = st.lists(st.sampled_from(TOKENS), max_size=40).map("".join)


@settings(max_examples=150, derandomize=True, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(YAMLISH)
def test_fuzz_text_loads_or_config_error(fuzz_dir, text):
    p = fuzz_dir / "text.yaml"
    p.write_text(text, encoding="utf-8")
    _load_or_config_error(p)
