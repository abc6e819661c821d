"""Strain limiting of a deformed mesh: shorten over-stretched edges toward a bound (Provot 1995).

Linear blend skinning stretches a garment where the body's own skin stretches (armpits and
shoulders under raised arms, where the skin stretches severalfold), and StVK forces there reach
thousands of times a vertex's weight. A few Jacobi sweeps of edge projection bring every edge
back under ``max_stretch`` times its rest length, moving both ends of an edge equally along it
and averaging the corrections per vertex; edges within the bound are untouched, so the rest of
the drape keeps its skinned shape. Batched over leading dimensions, differentiable (plain torch ops).

With a body, each sweep also pushes vertices closer than ``margin`` back out to it along the
body normal (the closest-point planes are re-queried every few sweeps), so a tight bound can pull
a garment onto a larger body without pulling it into it: a garment skinned onto a taller or wider
body than it was made for is stretched by the body's own growth, which a static drape does not
need where the garment can ride up.
"""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.geometry.proximity import BodySurface

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
    body: BodySurface | None = None,
    margin: float = 2e-3,
    requery_every: int = 10,
    momentum: float = 0.0,
) -> Tensor:
    """Project edges longer than ``max_stretch * rest`` toward that bound.

    Args:
        x: vertex positions [m], shape (..., V, 3).
        edges: undirected edges, shape (E, 2) int64.
        rest_lengths: their rest lengths [m], shape (E,) or broadcastable (..., E), > 0.
        max_stretch: the bound on length / rest length (> 1).
        iterations: Jacobi sweeps at most (stops early once every edge is within 1 % of the bound
            and every vertex above its floor).
        relaxation: over-relaxation of the averaged corrections (1 = plain Jacobi; < 2).
        body: posed bodies to keep the vertices out of (one per leading index: x of shape
            (B, V, 3) with B bodies, or (V, 3) with one), or None for no contact; queried in its
            own dtype.
        margin: after each sweep, a vertex is pushed back out to this distance from the body [m],
            or to its starting signed distance if that was smaller (strain limiting never moves
            a vertex deeper into the margin or the body; resolving what was already there is the
            collision handler's job).
        requery_every: sweeps between closest-point queries (the planes are held in between).
        momentum: heavy-ball momentum of the sweeps, in [0, 1) (0 = plain Jacobi); the velocity
            is reset whenever the total excess length grows (adaptive restart).

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
    if requery_every < 1:
        raise ValueError(f"requery_every must be >= 1, got {requery_every}")
    if not 0.0 <= momentum < 1.0:
        raise ValueError(f"momentum must be in [0, 1), got {momentum}")
    # Work on the leading dimensions flattened into one (B·V, 3) mesh of B disjoint copies: a
    # 2-D index_add is much faster on CPU than one along dim -2 of a 3-D tensor.
    shape, num_verts = x.shape, x.shape[-2]
    flat = x.reshape(-1, 3)
    copies = flat.shape[0] // num_verts
    offsets = (torch.arange(copies, device=x.device) * num_verts)[:, None]
    i = (edges[:, 0][None] + offsets).reshape(-1)
    j = (edges[:, 1][None] + offsets).reshape(-1)
    ends = torch.cat([i, j])
    bound = (max_stretch * rest_lengths.to(x.dtype)).expand(*shape[:-2], edges.shape[0]).reshape(-1)
    planes, floor = None, None
    velocity = torch.zeros_like(flat)
    previous = None
    x = flat
    for sweep in range(iterations):
        if body is not None and sweep % requery_every == 0:
            with torch.no_grad():  # in the body's dtype (the planes hold to its precision)
                query = body.query(x.detach().reshape(shape).to(body.verts.dtype))
            planes = query.closest.reshape(-1, 3).to(x.dtype), query.normal.reshape(-1, 3).to(x.dtype)
            if floor is None:  # never deeper than at the start, never into the margin
                floor = query.signed_distance.reshape(-1).to(x.dtype).clamp_max(margin)
        d = x[j] - x[i]
        length = d.norm(dim=-1)
        excess = (length - bound).clamp_min(0.0)
        inside = planes is not None and bool((_depth(x, planes, floor) > 1e-2 * margin).any())
        if not inside and not bool((excess > 1e-2 * bound).any()):
            break
        total = excess.sum()
        if previous is not None and bool(total > previous):
            velocity = torch.zeros_like(x)  # adaptive restart: the momentum overshot
        previous = total
        active = (excess > 0).to(x.dtype)
        # Each end moves half the excess along the edge; corrections are averaged per vertex.
        half = (0.5 * excess / length.clamp_min(1e-12)).unsqueeze(-1) * d
        shift = torch.zeros_like(x).index_add_(0, ends, torch.cat([half, -half]))
        count = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device).index_add_(0, ends, torch.cat([active, active]))
        x_new = x + relaxation * shift / count.clamp_min(1.0).unsqueeze(-1) + momentum * velocity
        if planes is not None:
            x_new = x_new + _depth(x_new, planes, floor).unsqueeze(-1) * planes[1]
        velocity = x_new - x
        x = x_new
    return x.reshape(shape)


def _depth(x: Tensor, planes: tuple[Tensor, Tensor], floor: Tensor) -> Tensor:
    """How far each vertex is below its floor (signed distance along its held closest-point
    plane) [m], >= 0."""
    closest, normal = planes
    return (floor - ((x - closest) * normal).sum(-1)).clamp_min(0.0)
