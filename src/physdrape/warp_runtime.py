"""The one place PhysDrape starts NVIDIA Warp (used by the body-surface queries, the garment
intersection tests, and Anny): initialised once, without its banner on stdout, where the CLI
prints JSON."""

from __future__ import annotations

import functools


@functools.cache
def warp():
    """The initialised `warp` module (its log level raised to warnings first)."""
    import warp as wp  # noqa: PLC0415  (heavy import, only needed for queries)

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    wp.init()  # a no-op if something initialised it already
    return wp
