"""Layer order: the outer piece of a multi-piece garment stays outside the inner one.

The physics has no self-collision, so where a top lies over trousers (or a jacket over a shirt)
nothing stops one layer from passing through the other. Where two pieces overlap on the
template, each outer vertex o is paired with the inner vertex i under it; the pair keeps o at
least δ outside i along the body's outward normal n at i (held fixed), a one-sided penalty:

    E_layer = Σ_p ½ k_p ReLU(δ_p − n_p·(x_o − x_i))²                          [J]
    f_o = k_p ReLU(·) n_p,   f_i = −f_o                                         [N]
    ∇²: [[H, −H], [−H, H]], H = k_p n_p n_pᵀ where the pair is active, else 0   (PSD)

The inner surface is taken as the plane through x_i normal to n_i, which holds while the layers
slide a few centimetres over each other. k_p [N/m] per pair.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["DEFAULT_LAYER_GAP", "DEFAULT_LAYER_STIFFNESS", "MIN_LAYER_GAP", "LayerOrder", "layer_energy", "layer_forces",
           "layer_pair_blocks", "layer_shortfall", "push_outer_out"]

#: Stiffness of one layer pair [N/m].
DEFAULT_LAYER_STIFFNESS = 1000.0
#: Normal separation δ kept between layers authored at least this far apart [m] (fabric and the air
#: between layers); layers authored closer keep their own separation (`LayerOrder.build`).
DEFAULT_LAYER_GAP = 4e-3
#: Least gap [m] of a pair authored closer than `DEFAULT_LAYER_GAP` (`LayerOrder.build`).
MIN_LAYER_GAP = 1e-3
#: Passes of `push_outer_out`: a piece pushed out may be the inner piece of another pair (a jacket
#: over a shirt over trousers), which the next pass then pushes.
PUSH_PASSES = 3


@dataclass(frozen=True)
class LayerOrder:
    """Outer-over-inner vertex pairs of a packed garment batch.

    Attributes:
        pairs: (P, 2) int64 [outer, inner] vertex indices (into the batch's ΣV vertices).
        normal: unit outward body normal n at the inner vertex (P, 3).
        gap: the least separation δ [m] (P,).
        stiffness: k [N/m] (P,).
    """

    pairs: Tensor
    normal: Tensor
    gap: Tensor
    stiffness: Tensor

    def to(self, dtype: torch.dtype | None = None, *, device: torch.device | str | None = None) -> LayerOrder:
        return LayerOrder(self.pairs.to(device=device), self.normal.to(device=device, dtype=dtype),
                          self.gap.to(device=device, dtype=dtype), self.stiffness.to(device=device, dtype=dtype))

    @staticmethod
    def build(pairs: Tensor, normal: Tensor, *, separation: Tensor | None = None,
              stiffness: float = DEFAULT_LAYER_STIFFNESS) -> LayerOrder:
        """Pairs (P, 2) with their inner normals (P, 3) and one stiffness [N/m]. The gap of a pair is
        its `separation` on the template [m] (P,) clamped to [`MIN_LAYER_GAP`, `DEFAULT_LAYER_GAP`]
        (layers authored closer than the default stay as close, not pushed apart), or
        `DEFAULT_LAYER_GAP` without it."""
        full = torch.ones(len(pairs), dtype=normal.dtype, device=normal.device)
        gap = DEFAULT_LAYER_GAP * full if separation is None else separation.to(full).clamp(MIN_LAYER_GAP,
                                                                                            DEFAULT_LAYER_GAP)
        return LayerOrder(pairs=pairs.to(device=normal.device), normal=normal, gap=gap, stiffness=stiffness * full)

    @staticmethod
    def cat(parts: list[LayerOrder]) -> LayerOrder:
        """One set of several (indices already offset into one batch)."""
        return LayerOrder(*(torch.cat([getattr(p, name) for p in parts])
                            for name in ("pairs", "normal", "gap", "stiffness")))


def layer_shortfall(x: Tensor, layers: LayerOrder) -> Tensor:
    """ReLU(δ − n·(x_o − x_i)) per pair [m], (..., P)."""
    d = x[..., layers.pairs[:, 0], :] - x[..., layers.pairs[:, 1], :]
    return (layers.gap.to(x.dtype) - (d * layers.normal.to(x.dtype)).sum(-1)).clamp_min(0.0)


def layer_energy(x: Tensor, layers: LayerOrder) -> Tensor:
    """½ k ReLU(δ − n·(x_o − x_i))² per pair [J], x (..., V, 3) → (..., P)."""
    return 0.5 * layers.stiffness.to(x.dtype) * layer_shortfall(x, layers) ** 2


def layer_forces(x: Tensor, layers: LayerOrder) -> Tensor:
    """f = −∇E_layer on every vertex [N], x (..., V, 3) → (..., V, 3)."""
    f = (layers.stiffness.to(x.dtype) * layer_shortfall(x, layers))[..., None] * layers.normal.to(x.dtype)  # on o
    out = torch.zeros_like(x).index_add_(-2, layers.pairs[:, 0], f)
    return out.index_add_(-2, layers.pairs[:, 1], -f)


def layer_pair_blocks(x: Tensor, layers: LayerOrder) -> Tensor:
    """H per pair (P, 3, 3) [N/m]: k n nᵀ where the pair is active, else 0; x (V, 3)."""
    n = layers.normal.to(x.dtype)
    active = (layer_shortfall(x, layers) > 0).to(x.dtype) * layers.stiffness.to(x.dtype)
    return active[:, None, None] * n[:, :, None] * n[:, None, :]


def push_outer_out(x: Tensor, layers: LayerOrder, allowed: Tensor | None = None) -> Tensor:
    """x (V, 3) [m] with each pair's outer vertex pushed out along the pair's normal n until its
    shortfall ReLU(δ − n·(x_o − x_i)) is at most `allowed` [m] (P,) (None: 0, the layers in
    order). An outer vertex in several pairs takes the largest push along their push-weighted
    mean normal; up to `PUSH_PASSES` passes for layers over layers. Not a term of the energy: a
    geometric step of the kinematic start (`pipeline`, allowed None) and of the collision
    handler (allowed: the shortfall before its push); outward only, differentiable in x."""
    outer, normal = layers.pairs[:, 0], layers.normal.to(x.dtype)
    for _ in range(PUSH_PASSES):
        excess = layer_shortfall(x, layers)
        if allowed is not None:
            excess = excess - allowed
        excess = excess.clamp_min(0.0)
        if not bool((excess > 0).any()):
            break
        size = x.new_zeros(x.shape[0]).scatter_reduce(0, outer, excess, "amax", include_self=True)
        direction = torch.nn.functional.normalize(torch.zeros_like(x).index_add(0, outer, excess[:, None] * normal),
                                                  dim=1)
        x = x + size[:, None] * direction
    return x
