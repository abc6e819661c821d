"""Shared fixtures. The Anny body is loaded once per test session (Anny caches its first build,
~1 min, on disk under ~/.cache/anny; later loads take about a second)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def anny_body():
    """The shared default-rig `AnnyBody` (104 bones, 13,348-vertex closed skin)."""
    from physdrape.body.anny_body import get_anny_body

    return get_anny_body("anny")


@pytest.fixture(scope="session")
def anny_cmu_body():
    """The `AnnyBody` on Anny's 31-bone ``cmu_mb`` rig (the BVH retarget target)."""
    from physdrape.body.anny_body import get_anny_body

    return get_anny_body("cmu_mb")
