"""The internal active force f_int (paper Eq. 4) and the garment's energy terms.

With a grip (`physics.grip`, `Cloth.grip`), stitches (`physics.stitches`, `Cloth.stitches`) or a
layer order (`physics.layers`, `Cloth.layers`) their terms are among them: every user of these functions (loss, solver, oracle, metrics) then
measures the same energy."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from physdrape.physics.bending import bend_energy, bend_forces
from physdrape.physics.cloth import Cloth
from physdrape.physics.gravity import gravity_energy, gravity_forces
from physdrape.physics.grip import grip_blocks, grip_energy, grip_forces
from physdrape.physics.layers import layer_energy, layer_forces
from physdrape.physics.stitches import stitch_energy, stitch_forces
from physdrape.physics.strain import strain_energy, strain_forces


def internal_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_int = f_strain + f_bend + f_grav (+ f_grip + f_stitch + f_layer) [N], x (..., V, 3) →
    (..., V, 3); equals −∇(E_strain + E_bend + E_grav (+ E_grip + E_stitch + E_layer))."""
    f = strain_forces(x, cloth) + bend_forces(x, cloth) + gravity_forces(x, cloth)
    ties = tie_forces(x, cloth)
    return f if ties is None else f + ties


def tie_forces(x: Tensor, cloth: Cloth) -> Tensor | None:
    """f_grip + f_stitch + f_layer [N], x (..., V, 3) → (..., V, 3): the forces of the terms that tie
    the cloth beyond its elements, those the cloth has (None: it has none)."""
    f = None
    if cloth.grip is not None:
        f = grip_forces(x, cloth.grip)
    if cloth.stitches is not None:
        stitch = stitch_forces(x, cloth.stitches)
        f = stitch if f is None else f + stitch
    if cloth.layers is not None:
        layer = layer_forces(x, cloth.layers)
        f = layer if f is None else f + layer
    return f


def energy_terms(x: Tensor, cloth: Cloth) -> dict[str, Tensor]:
    """Per-garment totals [J] of each internal energy term, x (..., V, 3) → {name: (..., G)}:
    strain, bend, gravity, and grip, stitch and layer when the cloth has them."""
    return {
        "strain": cloth.sum_per_garment(strain_energy(x, cloth), cloth.face_garment),
        "bend": cloth.sum_per_garment(bend_energy(x, cloth), cloth.hinge_garment),
        "gravity": cloth.sum_per_garment(gravity_energy(x, cloth), cloth.vert_garment),
        **tie_energy_terms(x, cloth),
    }


def tie_energy_terms(x: Tensor, cloth: Cloth) -> dict[str, Tensor]:
    """The per-garment totals [J] of the terms that tie the cloth beyond its elements, x (..., V, 3)
    → {name: (..., G)}: grip, stitch and layer, those the cloth has (none: {})."""
    terms = {}
    if cloth.grip is not None:
        terms["grip"] = cloth.sum_per_garment(grip_energy(x, cloth.grip), cloth.vert_garment[cloth.grip.index])
    if cloth.stitches is not None:
        terms["stitch"] = cloth.sum_per_garment(stitch_energy(x, cloth.stitches),
                                                cloth.vert_garment[cloth.stitches.pairs[:, 0]])
    if cloth.layers is not None:
        terms["layer"] = cloth.sum_per_garment(layer_energy(x, cloth.layers), cloth.vert_garment[cloth.layers.pairs[:, 0]])
    return terms


def internal_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_strain + E_bend + E_grav (+ E_grip + E_stitch + E_layer) per garment [J], x (..., V, 3) → (..., G)."""
    return sum(energy_terms(x, cloth).values())


#: Tangential share β of a layer pair's preconditioner block k (n nᵀ + β (I − n nᵀ)). The layer
#: energy resists only the normal approach (its exact block is k n nᵀ), but its pairs are fixed
#: at X_init and describe the pieces' overlap only while the pieces slide a few centimetres over
#: each other: a small tangential stiffness in the preconditioner slows their relative sliding
#: (not their sliding together, which the coarse space's coupling leaves free), and with β = 0
#: the MakeHuman suits of `bench/garments_stay_on.py` end with pieces crossing in places.
LAYER_SLIDE_DAMPING = 0.1


#: How far beyond its gap [m] a layer pair's preconditioner block still acts. The layer energy is
#: zero for a pair whose outer vertex is more than its gap outside the inner one, but a block held
#: on every pair ties the two pieces together in the preconditioner wherever they overlap on the
#: template, and slows a piece that has to settle apart from the one under it (a jacket sliding
#: down over trousers). Beyond the reach the pair's block and coupling are dropped
#: (`layer_link_weights`): on the MakeHuman suits 5 mm keeps the pieces uncrossed at T = 60,
#: 2 mm does not (`results/layer_link_reach.md`).
LAYER_LINK_REACH = 5e-3


@dataclass(frozen=True)
class Links:
    """The vertex pairs that the stitches and the layer order tie, and each pair's coupling.

    Attributes:
        pairs: (L, 2) int64 vertex indices, the stitches' pairs first, then the layer order's.
        blocks: H (L, 3, 3) [N/m], independent of x, with each pair's Hessian ≤ [[H, −H], [−H, H]]:
            k I for a stitch (≥ its exact block, `physics.stitches`), k (n nᵀ + β (I − n nᵀ)) for
            a layer pair (≥ its exact block k n nᵀ where the pair is active, `physics.layers`;
            β = `LAYER_SLIDE_DAMPING` unless the caller gives its own), each times its weight
            where the caller gives weights (`layer_link_weights`: the solver's steps keep the
            layer pairs within reach of acting).
    """

    pairs: Tensor
    blocks: Tensor


def layer_link_weights(cloth: Cloth, x: Tensor, *, reach: float | None = None) -> Tensor | None:
    """Which of the cloth's links act at x (V, 3) [m], (L,) in the cloth's dtype, 1 or 0, in
    `Links.pairs`' order: every stitch, and each layer pair whose outer vertex lies less than its
    gap plus `reach` [m] (None: `LAYER_LINK_REACH`) outside the inner one along the pair's normal;
    None when the cloth has no layer order."""
    if cloth.layers is None:
        return None
    layers, reach = cloth.layers, LAYER_LINK_REACH if reach is None else float(reach)
    apart = ((x[layers.pairs[:, 0]] - x[layers.pairs[:, 1]]) * layers.normal.to(x.dtype)).sum(-1)
    near = (apart < layers.gap.to(x.dtype) + reach).to(cloth.dtype)
    if cloth.stitches is None:
        return near
    return torch.cat([torch.ones(len(cloth.stitches.pairs), dtype=near.dtype, device=near.device), near])


def links(cloth: Cloth, *, slide: float | None = None, weight: Tensor | None = None) -> Links | None:
    """The cloth's `Links` in its dtype, or None when it has neither stitches nor a layer order;
    slide: the layer pairs' tangential share β (None: `LAYER_SLIDE_DAMPING`); weight: each link's
    factor (L,) (`layer_link_weights`; None: all 1)."""
    beta = LAYER_SLIDE_DAMPING if slide is None else float(slide)
    pairs, blocks = [], []
    if cloth.stitches is not None:
        k = cloth.stitches.stiffness.to(cloth.dtype)
        pairs.append(cloth.stitches.pairs)
        blocks.append(k[:, None, None] * torch.eye(3, dtype=cloth.dtype, device=k.device))
    if cloth.layers is not None:
        k, n = cloth.layers.stiffness.to(cloth.dtype), cloth.layers.normal.to(cloth.dtype)
        normal = n[:, :, None] * n[:, None, :]
        eye = torch.eye(3, dtype=cloth.dtype, device=k.device)
        pairs.append(cloth.layers.pairs)
        blocks.append(k[:, None, None] * (normal + beta * (eye - normal)))
    if not pairs:
        return None
    blocks = torch.cat(blocks)
    if weight is not None:
        blocks = blocks * weight.to(blocks.dtype)[:, None, None]
    return Links(torch.cat(pairs), blocks)


def extra_blocks(cloth: Cloth, *, slide: float | None = None, weight: Tensor | None = None) -> Tensor | None:
    """The per-vertex 3×3 blocks (V, 3, 3) [N/m] of the grip and the links for preconditioners:
    the grip's exact Hessian blocks, and H (`links`) at both ends of each link, the diagonal
    blocks of the links' PSD majorant [[H, −H], [−H, H]] (whose off-diagonal blocks the coarse
    space adds with the same weights, `physics.coarse_space`); None when the cloth has none.
    slide, weight: as `links`."""
    out = None
    if cloth.grip is not None:
        out = grip_blocks(cloth.grip, cloth.num_verts, dtype=cloth.dtype)
    tied = links(cloth, slide=slide, weight=weight)
    if tied is not None:
        blocks = torch.zeros(cloth.num_verts, 3, 3, dtype=cloth.dtype, device=tied.blocks.device).index_add_(
            0, tied.pairs.reshape(-1), tied.blocks.repeat_interleave(2, dim=0))
        out = blocks if out is None else out + blocks
    return out
