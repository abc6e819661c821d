"""Dihedral bending: energy per interior hinge and its analytic force (paper Eq. 2)."""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth


def _hinge_vectors(x: Tensor, hinges: Tensor):
    x0, x1, x2, x3 = (x[..., hinges[:, k], :] for k in range(4))
    edge = x1 - x0
    n_a = torch.linalg.cross(edge, x2 - x0)  # |n_a| = 2 · area of face (v0, v1, v2)
    n_b = torch.linalg.cross(x3 - x0, edge)  # |n_b| = 2 · area of face (v0, v3, v1)
    return x0, x2, x3, edge, n_a, n_b


def dihedral_angle(x: Tensor, hinges: Tensor) -> Tensor:
    """Signed dihedral angle θ of each hinge [rad], zero when flat, x (..., V, 3) → (..., H).

    θ = atan2((n_a × n_b)·ê, n_a·n_b) with the hinge's own face normals, so the sign does not
    depend on the faces' winding; atan2 keeps it finite for any non-degenerate hinge.
    """
    _, _, _, edge, n_a, n_b = _hinge_vectors(x, hinges)
    edge_len = edge.norm(dim=-1)
    sin_term = (torch.linalg.cross(n_a, n_b) * edge).sum(-1) / edge_len
    return torch.atan2(sin_term, (n_a * n_b).sum(-1))


def bend_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_bend per hinge = k_bend · l₀²/(4(A₀+A₁)) · θ²/2 [J], x (..., V, 3) → (..., H)."""
    theta = dihedral_angle(x, cloth.hinges)
    return 0.5 * cloth.bend_stiffness * theta * theta


def bend_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_i = −Σ_e k_bend s_e θ_e ∇_{x_i} θ_e (paper Eq. 2) [N], x (..., V, 3) → (..., V, 3).

    ∇θ in closed form: the opposite corners move along their face normals with 1/height,
    the shared-edge vertices take the balancing share by the corners' projections on the edge.
    """
    x0, x2, x3, edge, n_a, n_b = _hinge_vectors(x, cloth.hinges)
    edge_sq = (edge * edge).sum(-1)
    edge_len = edge_sq.sqrt()
    sin_term = (torch.linalg.cross(n_a, n_b) * edge).sum(-1) / edge_len
    theta = torch.atan2(sin_term, (n_a * n_b).sum(-1))
    grad2 = -(edge_len / (n_a * n_a).sum(-1))[..., None] * n_a
    grad3 = -(edge_len / (n_b * n_b).sum(-1))[..., None] * n_b
    alpha_a = (((x2 - x0) * edge).sum(-1) / edge_sq)[..., None]
    alpha_b = (((x3 - x0) * edge).sum(-1) / edge_sq)[..., None]
    grad0 = -(1.0 - alpha_a) * grad2 - (1.0 - alpha_b) * grad3
    grad1 = -alpha_a * grad2 - alpha_b * grad3
    scale = (-cloth.bend_stiffness * theta)[..., None, None]
    corner = scale * torch.stack([grad0, grad1, grad2, grad3], dim=-2)  # (..., H, 4, 3)
    out = torch.zeros_like(x)
    return out.index_add_(-2, cloth.hinges.reshape(-1), corner.flatten(-3, -2))
