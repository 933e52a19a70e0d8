"""The leaf classes a scenario may name in place of ours, each checked against the class it
replaces, so that ``feeder check`` names a wrong one before a run instead of a traceback in
it."""

from __future__ import annotations

from feeder_bt.behaviours.locate import Recognise
from feeder_bt.behaviours.retrieve import Pick
from feeder_bt.config.plugins import load_class
from feeder_bt.core.errors import ConfigError
from feeder_bt.core.model import Scenario
from feeder_bt.policy.adjusters import Adjuster
from feeder_bt.vision.locator import Locator

# the scenario key -> the class a leaf named there must subclass
LEAF_BASES: dict[str, type] = {
    "vision.leaf": Locator,
    "locate.leaf": Recognise,
    "retrieve.leaf": Pick,
    "adjust.leaf": Adjuster,
}


def leaf_class(scenario: Scenario, key: str) -> type | None:
    """The class the scenario names at ``key`` (``vision.leaf``, ...), or None for ours."""
    section, _ = key.split(".")
    spec = getattr(scenario, section).leaf
    if spec is None:
        return None
    try:
        return load_class(spec, scenario.path.parent, LEAF_BASES[key])
    except ConfigError as e:
        raise ConfigError(e.what, file=str(scenario.path), key=key) from None


def leaf_problems(scenario: Scenario) -> list[ConfigError]:
    """Every named leaf class that cannot be loaded or is not of its kind, one line each."""
    out = []
    for key in LEAF_BASES:
        try:
            leaf_class(scenario, key)
        except ConfigError as e:
            out.append(e)
    return out
