"""Graph inputs of the force-driven GNN (paper Eq. 6), computed at the kinematic initialisation."""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.geometry.garment import GarmentBatch, vertex_normals
from physdrape.physics.cloth import Cloth
from physdrape.physics.forces import internal_forces
from physdrape.tensor_memo import IdentityMemo

#: Material inputs are logged after this floor (λ may be 0 for a fabric without area stiffness).
MATERIAL_FLOOR = 1e-12
NODE_FEATURES = 11  # normal (3), signed distance (1), f_int (3), log μ, log λ, log k_bend, log m_i
#: With `ModelConfig.body_normal_inputs`: the body's outward direction at each vertex's closest point (3).
BODY_FEATURES = 3
#: With `ModelConfig.step_inputs`: the block-Jacobi move (3) and the coarse move (3) of the solver's first step.
STEP_FEATURES = 6
#: With `ModelConfig.step_newton_iterations`: the first step's truncated Newton move (3).
NEWTON_FEATURES = 3
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


def edge_features(x: Tensor, garments: GarmentBatch, edge_index: Tensor | None = None, level: Tensor | None = None,
                  levels: int = 0) -> Tensor:
    """e_ij = [x_ij, |x_ij|, x⁰_ij, l⁰_ij] per directed edge, (E', 8), plus a one-hot of the edge's
    level (levels + 1 columns) when `levels` > 0.

    Args:
        edge_index: (2, E') row 0 = sender; default the mesh's bidirectional edges.
        level: (E',) level of each edge (0 = mesh edge); needed when levels > 0.
    """
    edge_index = garments.edge_index if edge_index is None else edge_index
    if levels and level is None:
        raise ValueError("edge_features with levels > 0 needs the level of every edge")
    sender, receiver = edge_index
    current = x[receiver] - x[sender]
    constant = _CONSTANT_COLUMNS.get((garments, edge_index) + ((level,) if levels else ()), (levels, x.dtype),
                                     lambda: _constant_columns(garments, edge_index, level, levels, x.dtype))
    return torch.cat([current, current.norm(dim=-1, keepdim=True), constant], dim=-1)


def _constant_columns(garments: GarmentBatch, edge_index: Tensor, level: Tensor | None, levels: int,
                      dtype: torch.dtype) -> Tensor:
    """The edge features that do not depend on the positions: x⁰_ij, l⁰_ij and the level's one-hot."""
    sender, receiver = edge_index
    rest = (garments.rest[receiver] - garments.rest[sender]).to(dtype)
    parts = [rest, rest.norm(dim=-1, keepdim=True)]
    if levels:
        parts.append(torch.nn.functional.one_hot(level, levels + 1).to(dtype))
    return torch.cat(parts, dim=-1)


#: The position-free edge columns of a batch's graph (formed once per batch and graph: a drape of
#: the same garments packs the same batch and graph objects again).
_CONSTANT_COLUMNS = IdentityMemo(16)
