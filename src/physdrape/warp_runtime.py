"""The one place PhysDrape starts NVIDIA Warp (used by the body-surface queries, the solver's
preconditioner blocks, the garment intersection tests, and Anny): initialised once, without its
banner on stdout, where the CLI prints JSON; and the stream Warp work on a torch device runs on."""

from __future__ import annotations

import contextlib
import functools

import torch


@functools.cache
def warp():
    """The initialised `warp` module (its log level raised to warnings first)."""
    import warp as wp  # noqa: PLC0415  (heavy import, only needed for queries)

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    wp.init()  # a no-op if something initialised it already
    return wp


def torch_stream(device: torch.device):
    """A context running Warp work on torch's current stream of CUDA `device`, so that it is
    ordered with the torch ops that write its inputs and read its outputs; nothing on the CPU."""
    if device.type == "cuda":
        wp = warp()
        return wp.ScopedStream(wp.stream_from_torch(device))
    return contextlib.nullcontext()
