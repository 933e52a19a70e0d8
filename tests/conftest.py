"""Suite-wide settings: property tests are deterministic and never judged by the clock.

Hypothesis runs every property test with the ``feeder`` profile: examples derived from the
test itself (``derandomize``), no example database carried between runs, and neither a
per-example deadline nor the too-slow health check, both of which time the machine rather
than the code (on a loaded 2-core machine they fail good tests). ``HYPOTHESIS_PROFILE=
explore`` searches with fresh random examples instead, for finding new bugs by hand.

The browser tests' fixtures (``browser``, ``shots``) and the ``--update-shots`` option are
here; the rest of their one way of doing things is browser_helpers.py.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from tests.support.browser_helpers import ARGS, CHROMIUM, UPDATE_SHOTS, Shots

settings.register_profile("feeder", derandomize=True, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow], print_blob=True)
settings.register_profile("explore", parent=settings.get_profile("feeder"),
                          derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "feeder"))


# every run report a test writes, in its process or a child's, is checked against the
# published schema (``feeder schema report``; feeder_bt.analysis.run_report.check_written)
os.environ["FEEDER_CHECK_REPORTS"] = "1"


def pytest_configure(config: pytest.Config) -> None:
    """Compile the locator's kernels (feeder_bt/vision/kernels.py) once, in xdist's
    controller before the workers start: on a fresh clone each worker would compile them
    at once (about 13 s alone, 45 s four at once on two cores) while tests wait on the
    clock; from numba's cache each loads them in under a second."""
    if not hasattr(config, "workerinput"):
        from feeder_bt.vision.jit import warm
        warm()


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(UPDATE_SHOTS, action="store_true",
                     help="write the browser tests' screenshots into docs/ (otherwise they go "
                          "to pytest's temporary directory and the source tree is left as it "
                          "was)")


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """One headless Chromium for a browser test module (which called require_browser())."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


@pytest.fixture
def shots(request: pytest.FixtureRequest, tmp_path) -> Shots:
    """The docs' screenshots, taken into tmp_path; into docs/ too with --update-shots."""
    return Shots(tmp_path, request.config.getoption(UPDATE_SHOTS))
