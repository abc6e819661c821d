"""`physdrape.threads`: the split of an element table into parts with disjoint vertices,
`parallel_map`, and the split of a batch into groups for threads."""

from __future__ import annotations

import pytest
import torch

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet
from physdrape.threads import (
    MIN_ELEMENTS_PER_PART,
    balanced_groups,
    disjoint_parts,
    parallel_map,
    single_torch_thread,
)


def _sheets(count: int) -> GarmentBatch:
    return GarmentBatch.pack([Garment.from_mesh(*grid_sheet(40, 30 + k, width=0.6, height=0.5), name=f"sheet{k}")
                              for k in range(count)])


def test_parts_split_between_garments_only():
    batch = _sheets(3)
    faces = batch.faces
    starts = [0, *torch.cumsum(torch.bincount(batch.face_garment), 0).tolist()]
    parts = disjoint_parts(faces, 3)
    assert len(parts) == 3 and parts[0][0] == 0 and parts[-1][1] == faces.shape[0]
    assert all(lo in starts for lo, _ in parts)
    used = [set(faces[lo:hi].reshape(-1).tolist()) for lo, hi in parts]
    assert not (used[0] & used[1]) and not (used[1] & used[2])
    one = Garment.from_mesh(*grid_sheet(60, 60, width=0.6, height=0.5)).faces
    assert one.shape[0] >= 2 * MIN_ELEMENTS_PER_PART and disjoint_parts(one, 2) == [(0, one.shape[0])]
    assert disjoint_parts(faces[:100], 4) == [(0, 100)]


def test_parallel_map_returns_in_order_and_raises_what_an_item_raised():
    assert parallel_map(lambda k: k * k, list(range(7)), "test", workers=3) == [k * k for k in range(7)]
    assert parallel_map(lambda k: k + 1, [4], "test") == [5]

    def fail(k: int) -> int:
        if k == 3:
            raise KeyError(k)
        return k

    with pytest.raises(KeyError):
        parallel_map(fail, list(range(6)), "test", workers=2)


def test_balanced_groups_keep_a_key_together_and_balance_the_weights():
    keys = ["a", "b", "a", "c", "d", "b"]
    weights = [3.0, 1.0, 3.0, 2.0, 2.0, 1.0]  # a: 6, b: 2, c: 2, d: 2
    groups = balanced_groups(keys, weights, 2)
    assert sorted(i for g in groups for i in g) == list(range(6))
    assert all(g == sorted(g) for g in groups) and [g[0] for g in groups] == sorted(g[0] for g in groups)
    for key in set(keys):
        assert sum(any(keys[i] == key for i in g) for g in groups) == 1  # each key in one group
    loads = sorted(sum(weights[i] for i in g) for g in groups)
    assert loads == [6.0, 6.0]  # a alone; b, c and d together
    assert balanced_groups(keys, weights, 1) == [list(range(6))]
    assert balanced_groups(["x", "x", "x"], [1.0, 1.0, 1.0], 4) == [[0, 1, 2]]  # fewer keys than parts
    with pytest.raises(ValueError, match="part"):
        balanced_groups(keys, weights, 0)
    with pytest.raises(ValueError, match="weights"):
        balanced_groups(keys, weights[:2], 2)


def test_single_torch_thread_restores_the_thread_count():
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        with single_torch_thread():
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 2
        with pytest.raises(RuntimeError), single_torch_thread():
            raise RuntimeError("inside")
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_defined_once_defines_once_under_concurrent_first_calls():
    import threading
    import time

    from physdrape.warp_runtime import _DEFINERS, defined_once

    calls = []

    def define():
        calls.append(threading.get_ident())
        time.sleep(0.05)  # a slow definition: the other threads arrive meanwhile
        return object()

    once = defined_once(define)
    try:
        barrier = threading.Barrier(4)
        results = []

        def first_call():
            barrier.wait()
            results.append(once())

        workers = [threading.Thread(target=first_call) for _ in range(4)]
        for w in workers:
            w.start()
        for w in workers:
            w.join()
        assert len(calls) == 1 and len({id(r) for r in results}) == 1 and once() is results[0]
    finally:
        _DEFINERS.remove(once)  # not a module of the package: load_all_kernels must not load it
