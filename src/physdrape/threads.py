"""Thread pools for CPU work that releases the GIL (Warp kernels, torch ops): one pool per purpose
and size, made on first use and shared for the life of the process.

A pool's tasks must not wait on tasks of the same pool (a full pool would deadlock), so each
level of nesting has its own purpose: the chunked body-surface search (`geometry.body_bvh`)
runs inside the per-body X_init work of `pipeline.DrapePipeline.build`.
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor


@functools.cache
def thread_pool(purpose: str, workers: int) -> ThreadPoolExecutor:
    """The shared pool of `workers` threads for `purpose` (also the threads' name prefix)."""
    if workers < 1:
        raise ValueError(f"a thread pool needs at least one worker, got {workers}")
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"physdrape-{purpose}")
