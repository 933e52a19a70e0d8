"""Suite-wide settings: property tests are deterministic and never judged by the clock.

Hypothesis runs every property test with the ``feeder`` profile: examples derived from the
test itself (``derandomize``), no example database carried between runs, and neither a
per-example deadline nor the too-slow health check, both of which time the machine rather
than the code (on a loaded 2-core machine they fail good tests). ``HYPOTHESIS_PROFILE=
explore`` searches with fresh random examples instead, for finding new bugs by hand.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile("feeder", derandomize=True, database=None, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow], print_blob=True)
settings.register_profile("explore", parent=settings.get_profile("feeder"),
                          derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "feeder"))


# Files whose tests mostly wait on the wall clock (real-time runs, a browser, servers): run
# first, so that with two workers (-n 2 --dist loadfile) their waiting overlaps the other
# worker's computing instead of ending the run alone. A file's own tests keep their order.
WAIT_FIRST = ("test_emulated_run.py", "test_view_pty.py", "test_ui_http.py",
              "test_ui_browser.py")


def pytest_collection_modifyitems(session, config, items) -> None:
    rank = {name: i for i, name in enumerate(WAIT_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))   # stable: file order
