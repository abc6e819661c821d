"""`physdrape.threads`: the split of an element table into parts with disjoint vertices, and
`parallel_map`."""

from __future__ import annotations

import pytest
import torch

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet
from physdrape.threads import (
    MIN_ELEMENTS_PER_PART,
    disjoint_parts,
    parallel_map,
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
