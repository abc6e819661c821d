"""Strain limiting of a deformed mesh: shorten over-stretched edges toward a bound (Provot 1995).

Linear blend skinning stretches a garment where the body's own skin stretches (armpits and
shoulders under raised arms: ~3x on the Anny skin), and StVK forces there reach thousands of times
a vertex's weight. A few Jacobi sweeps of edge projection bring every edge back under
``max_stretch`` times its rest length, moving both ends of an edge equally along it and averaging
the corrections per vertex; edges within the bound are untouched, so the rest of the drape keeps
its skinned shape. Batched over leading dimensions, differentiable (plain torch ops).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["limit_edge_stretch", "max_edge_stretch"]


def max_edge_stretch(x: Tensor, edges: Tensor, rest_lengths: Tensor) -> Tensor:
    """Largest length / rest length over the edges, shape ``x.shape[:-2]``."""
    length = (x[..., edges[:, 1], :] - x[..., edges[:, 0], :]).norm(dim=-1)
    return (length / rest_lengths).amax(dim=-1)


def limit_edge_stretch(
    x: Tensor,
    edges: Tensor,
    rest_lengths: Tensor,
    *,
    max_stretch: float = 1.5,
    iterations: int = 100,
    relaxation: float = 1.5,
) -> Tensor:
    """Project edges longer than ``max_stretch * rest`` toward that bound.

    Args:
        x: vertex positions [m], shape (..., V, 3).
        edges: undirected edges, shape (E, 2) int64.
        rest_lengths: their rest lengths [m], shape (E,) or broadcastable (..., E), > 0.
        max_stretch: the bound on length / rest length (> 1).
        iterations: Jacobi sweeps at most (stops early once every edge is within 1 % of the bound).
        relaxation: over-relaxation of the averaged corrections (1 = plain Jacobi; < 2).

    Returns:
        positions of the same shape; edges that were within the bound and far from stretched
        ones keep their lengths exactly.
    """
    if not max_stretch > 1.0:
        raise ValueError(f"max_stretch must be > 1, got {max_stretch}")
    if not 0.0 < relaxation < 2.0:
        raise ValueError(f"relaxation must be in (0, 2), got {relaxation}")
    if edges.ndim != 2 or edges.shape[1] != 2 or rest_lengths.shape[-1:] != edges.shape[:1]:
        raise ValueError(f"edges must be (E, 2) and rest_lengths (..., E), got {tuple(edges.shape)} and "
                         f"{tuple(rest_lengths.shape)}")
    i, j = edges[:, 0], edges[:, 1]
    bound = max_stretch * rest_lengths.to(x.dtype)
    for _ in range(iterations):
        d = x[..., j, :] - x[..., i, :]
        length = d.norm(dim=-1)
        excess = (length - bound).clamp_min(0.0)
        if not bool((excess > 1e-2 * bound).any()):
            break
        active = (excess > 0).to(x.dtype)
        # Each end moves half the excess along the edge; corrections are averaged per vertex.
        half = (0.5 * excess / length.clamp_min(1e-12)).unsqueeze(-1) * d
        shift = torch.zeros_like(x).index_add(-2, i, half).index_add(-2, j, -half)
        count = torch.zeros(x.shape[:-1], dtype=x.dtype, device=x.device)
        count = count.index_add(-1, i, active).index_add(-1, j, active)
        x = x + relaxation * shift / count.clamp_min(1.0).unsqueeze(-1)
    return x
