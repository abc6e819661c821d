"""`geometry.neighbours.nearest_within` (a hash grid searched by one Warp kernel) against
scipy's k-d tree, in both precisions and on every available device."""

from __future__ import annotations

import pytest
import torch
from device_params import DEVICES
from scipy.spatial import cKDTree

from physdrape.geometry.neighbours import nearest_within


def _expected(source: torch.Tensor, target: torch.Tensor, k: int, radius: float) -> list[tuple[int, int]]:
    """The k-d tree's pairs (float64 on the same coordinates), by source, nearest first."""
    dist, idx = cKDTree(target.double().numpy()).query(source.double().numpy(), k=k, distance_upper_bound=radius)
    dist, idx = dist.reshape(len(source), k), idx.reshape(len(source), k)
    return [(s, int(idx[s, c])) for s in range(len(source)) for c in range(k) if dist[s, c] <= radius]


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_k_nearest_within_the_radius_in_order(device, dtype):
    """Random points about the origin (negative coordinates too), a radius that holds fewer than
    k for some sources and more for most: the same pairs as the k-d tree, in the same order
    (sorted by source, nearest first)."""
    gen = torch.Generator().manual_seed(3)
    source = ((torch.rand(400, 3, generator=gen, dtype=torch.float64) - 0.5) * 0.2).to(dtype)
    target = ((torch.rand(600, 3, generator=gen, dtype=torch.float64) - 0.5) * 0.2).to(dtype)
    i, j = nearest_within(source.to(device), target.to(device), k=3, radius=0.02)
    assert i.device.type == device and i.dtype == j.dtype == torch.int64
    expected = _expected(source, target, 3, 0.02)
    assert list(zip(i.tolist(), j.tolist())) == expected
    counts = torch.bincount(i.cpu(), minlength=len(source))
    assert (counts == 3).sum() > 100 and ((counts > 0) & (counts < 3)).sum() > 10  # both cases occur


def test_points_far_apart_and_spread_wide():
    """Two clusters a hundred metres apart (the grid's table wraps: distant cells share slots) and
    a k larger than the target: only the true neighbours within the radius, none across."""
    gen = torch.Generator().manual_seed(5)
    blob = torch.rand(50, 3, generator=gen, dtype=torch.float64) * 0.05
    source = torch.cat([blob, blob + 100.0])
    target = torch.cat([blob[:20] + 1e-3, blob[:20] + 100.0 + 1e-3])
    i, j = nearest_within(source, target, k=50, radius=0.03)
    assert list(zip(i.tolist(), j.tolist())) == _expected(source, target, 40, 0.03)
    assert ((i < 50) == (j < 20)).all()


def test_empty_and_bad_input():
    points = torch.rand(5, 3, dtype=torch.float64)
    for source, target, k in ((points[:0], points, 3), (points, points[:0], 3), (points, points, 0)):
        i, j = nearest_within(source, target, k=k, radius=0.1)
        assert len(i) == len(j) == 0
    with pytest.raises(TypeError, match="share a dtype"):
        nearest_within(points, points.float(), k=1, radius=0.1)
    with pytest.raises(ValueError, match="radius > 0"):
        nearest_within(points, points, k=1, radius=0.0)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        nearest_within(points[:, :2], points, k=1, radius=0.1)
