"""Thread pools for CPU work that releases the GIL (Warp kernels, torch ops): one pool per purpose
and size, made on first use and shared for the life of the process; and the split of an element
kernel's launch into parts that touch disjoint vertices.

A pool's tasks must not wait on tasks of the same pool (a full pool would deadlock), so each
level of nesting has its own purpose: the chunked body-surface search (`geometry.body_bvh`)
runs inside the per-body X_init work of `pipeline.DrapePipeline.build`.
"""

from __future__ import annotations

import collections
import functools
import itertools
import weakref
from concurrent.futures import ThreadPoolExecutor

import torch
from torch import Tensor


@functools.cache
def thread_pool(purpose: str, workers: int) -> ThreadPoolExecutor:
    """The shared pool of `workers` threads for `purpose` (also the threads' name prefix)."""
    if workers < 1:
        raise ValueError(f"a thread pool needs at least one worker, got {workers}")
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"physdrape-{purpose}")


#: Below this many elements per part a launch is not split (the threads' overhead would dominate).
MIN_ELEMENTS_PER_PART = 2048

#: Split points of element tables already seen, by the id of the table: a solver launches over
#: the same faces and hinges dozens of times per drape.
_SPLITS: collections.OrderedDict[int, tuple[weakref.ref, int, Tensor]] = collections.OrderedDict()


def disjoint_parts(elements: Tensor, parts: int) -> list[tuple[int, int]]:
    """Up to `parts` ranges [lo, hi) covering the rows of `elements` (N, k) (vertex indices of
    faces, hinges, edges) such that no vertex is used by two ranges: a kernel that sums per-element
    contributions into its vertices can run the ranges on different threads, each vertex summed
    by one of them in the order a single launch would. A batch of garments packed one after the
    other splits between garments; one garment usually does not split (one range).

    The ranges end at the split points nearest to equal shares, each range at least
    `MIN_ELEMENTS_PER_PART` long.
    """
    n = elements.shape[0]
    parts = min(parts, n // MIN_ELEMENTS_PER_PART)
    if parts < 2:
        return [(0, n)]
    hit = _SPLITS.get(id(elements))
    if hit is not None and hit[0]() is elements and hit[1] == elements._version:
        splits = hit[2]
    else:  # row s starts a new range where all rows before it use lower vertices than all from it
        lowest = elements.min(dim=1).values.flip(0).cummin(0).values.flip(0)
        highest = elements.max(dim=1).values.cummax(0).values
        splits = (torch.nonzero(highest[:-1] < lowest[1:])[:, 0] + 1).cpu()
        _SPLITS[id(elements)] = (weakref.ref(elements), elements._version, splits)
        while len(_SPLITS) > 64:
            _SPLITS.popitem(last=False)
    bounds = [0]
    for j in range(1, parts):
        if not splits.numel():
            break
        target = j * n / parts
        nearest = int(splits[int((splits.to(torch.float64) - target).abs().argmin())])
        if nearest - bounds[-1] >= MIN_ELEMENTS_PER_PART and n - nearest >= MIN_ELEMENTS_PER_PART:
            bounds.append(nearest)
    bounds = sorted(set(bounds)) + [n]
    return list(itertools.pairwise(bounds))


def even_parts(n: int, parts: int) -> list[tuple[int, int]]:
    """Up to `parts` ranges of nearly equal length covering [0, n), each at least
    `MIN_ELEMENTS_PER_PART` long (for kernels whose elements write nothing they share)."""
    parts = max(1, min(parts, n // MIN_ELEMENTS_PER_PART))
    bounds = [n * j // parts for j in range(parts + 1)]
    return list(itertools.pairwise(bounds))


def run_parts(launch, ranges: list[tuple[int, int]], purpose: str) -> None:
    """launch(lo, hi) for every range: on the `purpose` pool when there are several (Warp kernels
    and torch ops release the GIL), else here."""
    if len(ranges) == 1:
        launch(*ranges[0])
        return
    pool = thread_pool(purpose, len(ranges))
    for job in [pool.submit(launch, lo, hi) for lo, hi in ranges]:
        job.result()
