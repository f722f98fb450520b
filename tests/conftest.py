"""Hypothesis profiles: ``ci`` is derandomised, so a CI run tries the same examples every time.

``HYPOTHESIS_PROFILE`` picks the profile; without it, ``ci`` when ``CI`` is set (as CI services
do) and ``dev`` otherwise. ``scripts/test.sh`` always uses ``ci``.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

settings.register_profile(
    "ci",
    derandomize=True,  # examples derived from each test's name: the same on every run
    deadline=None,  # per-example timing on a shared 2-core runner is noise, not a failure
    suppress_health_check=[HealthCheck.too_slow],
    print_blob=True,
)
settings.register_profile("dev", print_blob=True)
_DEFAULT = "ci" if os.environ.get("CI") else "dev"
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE") or _DEFAULT)
