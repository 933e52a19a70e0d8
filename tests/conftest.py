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
