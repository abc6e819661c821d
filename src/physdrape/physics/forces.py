"""The internal active force f_int (paper Eq. 4) and the garment's energy terms.

With a grip (`physics.grip`, `Cloth.grip`), stitches (`physics.stitches`, `Cloth.stitches`) or a
layer order (`physics.layers`, `Cloth.layers`) their terms are among them: every user of these functions (loss, solver, oracle, metrics) then
measures the same energy."""

from __future__ import annotations

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
    if cloth.grip is not None:
        f = f + grip_forces(x, cloth.grip)
    if cloth.stitches is not None:
        f = f + stitch_forces(x, cloth.stitches)
    if cloth.layers is not None:
        f = f + layer_forces(x, cloth.layers)
    return f


def energy_terms(x: Tensor, cloth: Cloth) -> dict[str, Tensor]:
    """Per-garment totals [J] of each internal energy term, x (..., V, 3) → {name: (..., G)}:
    strain, bend, gravity, and grip, stitch and layer when the cloth has them."""
    terms = {
        "strain": cloth.sum_per_garment(strain_energy(x, cloth), cloth.face_garment),
        "bend": cloth.sum_per_garment(bend_energy(x, cloth), cloth.hinge_garment),
        "gravity": cloth.sum_per_garment(gravity_energy(x, cloth), cloth.vert_garment),
    }
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


def extra_blocks(cloth: Cloth) -> Tensor | None:
    """3×3 blocks per vertex (V, 3, 3) [N/m] of a PSD majorant of the grip's, the stitches' and
    the layer order's Hessian, independent of x (the grip's exact blocks; k I at both ends of a
    stitch or layer pair, ≥ their exact H), for preconditioners; None when the cloth has none."""
    out = None
    if cloth.grip is not None:
        out = grip_blocks(cloth.grip, cloth.num_verts, dtype=cloth.dtype)
    for pairs in (cloth.stitches, cloth.layers):
        if pairs is None:
            continue
        k = pairs.stiffness.to(cloth.dtype)
        eye = torch.eye(3, dtype=cloth.dtype, device=k.device)
        blocks = torch.zeros(cloth.num_verts, 3, 3, dtype=cloth.dtype, device=k.device).index_add_(
            0, pairs.pairs.reshape(-1), (k[:, None, None] * eye).repeat_interleave(2, dim=0))
        out = blocks if out is None else out + blocks
    return out
