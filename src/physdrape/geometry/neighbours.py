"""Each point's nearest points of another set within a radius, on a hash grid (Warp).

A multi-piece garment's layer pairs join each vertex of one piece to its few nearest vertices of
another within a few centimetres (`garments.layering.layer_pairs` on the template,
`physics.layers.follow_pairs` at the current positions, in the oracle's iterations and every
drape's measured energy). Comparing every vertex with every other costs the product of the
pieces' sizes; a hash grid of cells as wide as the radius visits only the 27 cells around a
point. One Warp kernel on the CPU and on CUDA: per source point, the
candidates of those cells within the radius, kept sorted by distance in its own row of the
outputs (k is small: an insertion sort).
"""

from __future__ import annotations

from typing import Any

import torch
from torch import Tensor

from physdrape.warp_runtime import defined_once, torch_stream, warp

__all__ = ["nearest_within"]

#: Cells per axis of the hash grid's table (points of any extent hash into it; a larger table has
#: fewer collisions of distant cells, a smaller one builds faster).
GRID_CELLS = 32


def nearest_within(source: Tensor, target: Tensor, *, k: int, radius: float) -> tuple[Tensor, Tensor]:
    """Each source point's k nearest target points within `radius` [m] (distance ≤ radius): the
    (source index, target index) of every such pair, (P,) int64 each, sorted by source and, for
    one source, by distance. source (S, 3), target (T, 3), one floating dtype (float32 or
    float64: distances in it) and device."""
    if source.ndim != 2 or source.shape[-1] != 3 or target.ndim != 2 or target.shape[-1] != 3:
        raise ValueError(f"source and target must be (N, 3) points, got {tuple(source.shape)} and "
                         f"{tuple(target.shape)}")
    if source.dtype != target.dtype or source.dtype not in (torch.float32, torch.float64):
        raise TypeError(f"source and target must share a dtype, float32 or float64; got {source.dtype} and "
                        f"{target.dtype}")
    if not radius > 0.0 or k < 0:
        raise ValueError(f"need radius > 0 and k >= 0, got {radius} and {k}")
    k = min(k, len(target))
    if k == 0 or len(source) == 0:
        empty = torch.zeros(0, dtype=torch.int64, device=source.device)
        return empty, empty.clone()
    wp, kernel = _kernels()
    double = source.dtype == torch.float64
    vec, scalar = (wp.vec3d, wp.float64) if double else (wp.vec3f, wp.float32)
    source, target = source.detach().contiguous(), target.detach().contiguous()
    dist = torch.full((len(source), k), float("inf"), dtype=source.dtype, device=source.device)
    index = torch.full((len(source), k), -1, dtype=torch.int32, device=source.device)
    device = wp.device_from_torch(source.device)
    with torch_stream(source.device):
        grid = wp.HashGrid(GRID_CELLS, GRID_CELLS, GRID_CELLS, device=device, dtype=scalar)
        points = wp.from_torch(target, dtype=vec, requires_grad=False)
        grid.build(points, float(radius))
        wp.launch(kernel, dim=len(source), device=device,
                  inputs=[wp.uint64(grid.id), wp.from_torch(source, dtype=vec), points, scalar(radius), k,
                          wp.from_torch(dist, dtype=scalar), wp.from_torch(index, dtype=wp.int32)])
    rows, slot = (index >= 0).nonzero(as_tuple=True)
    return rows, index[rows, slot].long()


@defined_once
def _kernels():
    """The search kernel (generic in the coordinates' precision): per source point s, every
    candidate of the grid's cells around it within `radius` is inserted into row s of `dist` /
    `index` (ascending distance, inf / −1 where there are fewer than k); a candidate no nearer
    than the k-th kept is skipped, so of equally distant ones the first visited stays."""
    wp = warp()

    @wp.kernel(enable_backward=False)
    def nearest(grid: wp.uint64, source: wp.array(dtype=Any), target: wp.array(dtype=Any), radius: Any, k: int,
                dist: wp.array2d(dtype=Any), index: wp.array2d(dtype=wp.int32)):
        s = wp.tid()
        p = source[s]
        query = wp.hash_grid_query(grid, p, radius)
        t = int(0)
        while wp.hash_grid_query_next(query, t):
            d = wp.length(target[t] - p)
            if d <= radius and d < dist[s, k - 1]:
                j = k - 1
                while j > 0 and dist[s, j - 1] > d:
                    dist[s, j] = dist[s, j - 1]
                    index[s, j] = index[s, j - 1]
                    j -= 1
                dist[s, j] = d
                index[s, j] = t

    return wp, nearest
