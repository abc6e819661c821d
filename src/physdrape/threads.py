"""Parallel CPU work on threads, for work that releases the GIL (Warp kernels, torch ops): shared
pools, one per purpose and size, made on first use; `parallel_map`, in which the calling thread
works along; and the split of an element kernel's launch into parts that touch disjoint vertices.

A memory-bound kernel (the element kernels) gains less from a second thread than a compute-bound
one, and a part of a fraction of a millisecond can take less time than waking a pool thread:
`parallel_map` keeps the calling thread busy, so that a pool thread that wakes late does not cost
its part, and one garment's launches are not split at all.
"""

from __future__ import annotations

import functools
import itertools
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch
from torch import Tensor

from physdrape.tensor_memo import TensorMemo

T = TypeVar("T")
R = TypeVar("R")


@functools.cache
def thread_pool(purpose: str, workers: int) -> ThreadPoolExecutor:
    """The shared pool of `workers` threads for `purpose` (also the threads' name prefix)."""
    if workers < 1:
        raise ValueError(f"a thread pool needs at least one worker, got {workers}")
    return ThreadPoolExecutor(max_workers=workers, thread_name_prefix=f"physdrape-{purpose}")


#: Below this many elements per part a launch is not split (the threads' overhead would dominate).
MIN_ELEMENTS_PER_PART = 2048

#: Split points of element tables already seen: a solver launches over the same faces and hinges
#: dozens of times per drape.
_SPLITS = TensorMemo(64)


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
    splits = _SPLITS.get(elements, _split_points)
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


def _split_points(elements: Tensor) -> Tensor:
    """The rows s of `elements` (N, k) before which every row uses lower vertices than every row
    from s on (CPU int64)."""
    lowest = elements.min(dim=1).values.flip(0).cummin(0).values.flip(0)
    highest = elements.max(dim=1).values.cummax(0).values
    return (torch.nonzero(highest[:-1] < lowest[1:])[:, 0] + 1).cpu()


def parallel_map(fn: Callable[[T], R], items: Sequence[T], purpose: str, workers: int | None = None) -> list[R]:
    """[fn(item) for item in items], the items shared between this thread and workers − 1 threads
    of the `purpose` pool (Warp kernels and torch ops release the GIL); workers: at most this
    many threads in all (None: one per item).

    Every thread, this one included, claims the next unclaimed item until none is left, and this
    thread returns once every item is done: a pool thread that the OS wakes late (milliseconds
    on a busy machine, longer than a kernel's part) finds nothing left rather than holding the
    others up. The first exception raised by fn is raised here, after every item has run.
    """
    workers = len(items) if workers is None else min(workers, len(items))
    if workers < 2:
        return [fn(item) for item in items]
    results: list = [None] * len(items)
    errors: list[BaseException] = []
    claims = itertools.count()  # next() of a count is atomic under the GIL
    finished = threading.Condition()
    left = [len(items)]

    def work() -> None:
        while (k := next(claims)) < len(items):
            try:
                results[k] = fn(items[k])
            except BaseException as exc:  # noqa: BLE001  (re-raised in the calling thread)
                errors.append(exc)
            with finished:
                left[0] -= 1
                if not left[0]:
                    finished.notify_all()

    pool = thread_pool(purpose, workers - 1)
    for _ in range(workers - 1):
        pool.submit(work)
    work()
    with finished:
        finished.wait_for(lambda: not left[0])
    if errors:
        raise errors[0]
    return results


def run_parts(launch: Callable[[int, int], None], ranges: list[tuple[int, int]], purpose: str) -> None:
    """launch(lo, hi) for every range, in parallel where there are several (`parallel_map`)."""
    parallel_map(lambda bounds: launch(*bounds), ranges, purpose)
