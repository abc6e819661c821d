"""Graph inputs of the force-driven GNN (paper Eq. 6), computed at the kinematic initialisation."""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.geometry.garment import GarmentBatch, vertex_normals
from physdrape.physics.cloth import Cloth
from physdrape.physics.forces import internal_forces

#: Material inputs are logged after this floor (λ may be 0 for a fabric without area stiffness).
MATERIAL_FLOOR = 1e-12
NODE_FEATURES = 11  # normal (3), signed distance (1), f_int (3), log μ, log λ, log k_bend, log m_i
EDGE_FEATURES = 8  # x_ij (3), |x_ij| (1), rest x⁰_ij (3), l⁰_ij (1)


def node_features(x: Tensor, garments: GarmentBatch, cloth: Cloth, signed_distance: Tensor) -> Tensor:
    """h_i = [n_i, d_i, f_int,i, m_i] with the material on a log scale, (ΣV, 11).

    Args:
        x: garment positions [m], (ΣV, 3); signed_distance: to the body [m], (ΣV,).
    """
    normals = vertex_normals(x, garments.faces)
    force = internal_forces(x, cloth)
    material = torch.cat([cloth.stiffness[cloth.vert_garment], cloth.mass[:, None]], dim=-1)
    return torch.cat([normals, signed_distance[:, None], force, torch.log(material.to(x.dtype).clamp_min(MATERIAL_FLOOR))], dim=-1)


def edge_features(x: Tensor, garments: GarmentBatch) -> Tensor:
    """e_ij = [x_ij, |x_ij|, x⁰_ij, l⁰_ij] on the bidirectional edges (edge_index), (2ΣE, 8)."""
    sender, receiver = garments.edge_index
    current = x[receiver] - x[sender]
    rest = (garments.rest[receiver] - garments.rest[sender]).to(x.dtype)
    return torch.cat(
        [current, current.norm(dim=-1, keepdim=True), rest, rest.norm(dim=-1, keepdim=True)], dim=-1
    )
