"""Parallel CPU work on threads, for work that releases the GIL (Warp kernels, torch ops): shared
pools, one per purpose and size, made on first use; `parallel_map`, in which the calling thread
works along; and the split of an element kernel's launch into parts that touch disjoint vertices.

A memory-bound kernel (the element kernels) gains less from a second thread than a compute-bound
one, and a part of a fraction of a millisecond can take less time than waking a pool thread:
`parallel_map` keeps the calling thread busy, so that a pool thread that wakes late does not cost
its part, and one garment's launches are not split at all.

A batch of garments on several bodies can also be split whole between threads
(`balanced_groups`, `single_torch_thread`): each thread drapes its own group from posing to
metrics, its torch ops inline, so that the many small ops of a drape run side by side instead
of one after the other on torch's shared pool. BLAS calls inside such work run on one BLAS
thread (`one_blas_thread`).
"""

from __future__ import annotations

import contextlib
import functools
import itertools
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import torch
from threadpoolctl import ThreadpoolController
from torch import Tensor

from physdrape.tensor_memo import TensorMemo
from physdrape.warp_runtime import load_all_kernels

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

    The package's Warp kernels are loaded on the CPU before the threads start
    (`warp_runtime.load_all_kernels`: two threads' first launches into a module not loaded yet
    can crash the process).
    """
    workers = len(items) if workers is None else min(workers, len(items))
    if workers < 2:
        return [fn(item) for item in items]
    load_all_kernels("cpu")
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


def balanced_groups(keys: Sequence[object], weights: Sequence[float], parts: int) -> list[list[int]]:
    """The indices of items split into at most `parts` groups of nearly equal total weight, the
    items of one key always in one group (`keys` hashable; items that share a key share state,
    e.g. the jobs of one posed body share its surface, and must not run on two threads at once).

    Keys go heaviest first to the lightest group so far; each group lists its items in order, and
    the groups are ordered by their first item. Empty groups are dropped (fewer keys than parts).
    """
    if parts < 1:
        raise ValueError(f"need at least one part, got {parts}")
    if len(keys) != len(weights):
        raise ValueError(f"{len(keys)} keys but {len(weights)} weights")
    members: dict[object, list[int]] = {}
    for i, key in enumerate(keys):
        members.setdefault(key, []).append(i)
    groups: list[list[int]] = [[] for _ in range(min(parts, len(members)))]
    load = [0.0] * len(groups)
    for items in sorted(members.values(), key=lambda m: (-sum(weights[i] for i in m), m[0])):
        lightest = min(range(len(groups)), key=lambda g: (load[g], g))
        groups[lightest].extend(items)
        load[lightest] += sum(weights[i] for i in items)
    return sorted((sorted(g) for g in groups if g), key=lambda g: g[0])


@contextlib.contextmanager
def single_torch_thread() -> Iterator[None]:
    """torch's intra-op threads set to 1 inside the block (restored after it): for work that is
    itself split between threads, each of which should run its torch ops inline instead of
    sharing (and oversubscribing) torch's one pool. The setting is process-wide."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@functools.cache
def blas_controller() -> ThreadpoolController:
    """The BLAS libraries loaded in the process (SciPy's LAPACK among them), found once."""
    return ThreadpoolController()


@contextlib.contextmanager
def one_blas_thread():
    """A context in which BLAS calls (the coarse space's band factorisations and solves) run on the
    calling thread alone: the solver brings its own threads (torch's, or a batch's garment groups
    side by side), and BLAS threads of its own beside them, waiting between these small calls,
    would take those threads' cores (a drape on two torch threads took twice as long).

    The BLAS thread count is process-wide: the first thread to enter sets it to 1 and the last to
    leave restores what it was, so that threads draping side by side, entering and leaving in any
    order, all run on one BLAS thread and leave the process's setting as they found it."""
    global _blas_limit, _blas_users
    with _BLAS_LOCK:
        if not _blas_users:
            _blas_limit = blas_controller().limit(limits=1, user_api="blas")
        _blas_users += 1
    try:
        yield
    finally:
        with _BLAS_LOCK:
            _blas_users -= 1
            if not _blas_users:
                _blas_limit.restore_original_limits()
                _blas_limit = None


_BLAS_LOCK = threading.Lock()
_blas_limit = None  # the limit in force while `_blas_users` > 0 threads are inside `one_blas_thread`
_blas_users = 0
