"""Slow torch twins of the Warp element kernels (`physdrape.physics.element_kernels`): the
StVK energy and force per face, the dihedral angle, bending energy and force per hinge, written
as batched torch ops. Differentiable any number of times, so the tests also take the oracle's
element Hessians from them."""

import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.strain import deformation_gradient, green_strain, stress


def strain_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """V (μ‖G‖²_F + λ/2 tr(G)²) per face, x (..., V, 3) → (..., F)."""
    G = green_strain(deformation_gradient(x, cloth))
    trace = G[..., 0, 0] + G[..., 1, 1]
    return cloth.volume * (cloth.mu * (G * G).sum((-1, -2)) + 0.5 * cloth.lam * trace * trace)


def strain_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """−V P Dm⁻ᵀ summed onto the corners, P = F S, x (..., V, 3) → (..., V, 3)."""
    F = deformation_gradient(x, cloth)
    S = stress(green_strain(F), cloth)
    H = -(cloth.volume[:, None, None] * (F @ S)) @ cloth.rest_inv.transpose(-1, -2)
    f1, f2 = H[..., 0], H[..., 1]
    corner = torch.stack([-(f1 + f2), f1, f2], dim=-2)
    return torch.zeros_like(x).index_add_(-2, cloth.faces.reshape(-1), corner.flatten(-3, -2))


def _hinge_vectors(x: Tensor, hinges: Tensor):
    x0, x1, x2, x3 = (x[..., hinges[:, k], :] for k in range(4))
    edge = x1 - x0
    return x0, x2, x3, edge, torch.linalg.cross(edge, x2 - x0), torch.linalg.cross(x3 - x0, edge)


def dihedral_angle(x: Tensor, hinges: Tensor) -> Tensor:
    """atan2((n_a × n_b)·ê, n_a·n_b) per hinge, x (..., V, 3) → (..., H)."""
    _, _, _, edge, n_a, n_b = _hinge_vectors(x, hinges)
    sin_term = (torch.linalg.cross(n_a, n_b) * edge).sum(-1) / edge.norm(dim=-1)
    return torch.atan2(sin_term, (n_a * n_b).sum(-1))


def bend_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """k θ²/2 per hinge, x (..., V, 3) → (..., H)."""
    theta = dihedral_angle(x, cloth.hinges)
    return 0.5 * cloth.bend_stiffness * theta * theta


def bend_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """−k θ ∇θ summed onto the hinge's vertices, ∇θ in closed form, x (..., V, 3) → (..., V, 3)."""
    x0, x2, x3, edge, n_a, n_b = _hinge_vectors(x, cloth.hinges)
    edge_sq = (edge * edge).sum(-1)
    edge_len = edge_sq.sqrt()
    theta = torch.atan2((torch.linalg.cross(n_a, n_b) * edge).sum(-1) / edge_len, (n_a * n_b).sum(-1))
    grad2 = -(edge_len / (n_a * n_a).sum(-1))[..., None] * n_a
    grad3 = -(edge_len / (n_b * n_b).sum(-1))[..., None] * n_b
    alpha_a = (((x2 - x0) * edge).sum(-1) / edge_sq)[..., None]
    alpha_b = (((x3 - x0) * edge).sum(-1) / edge_sq)[..., None]
    grad0 = -(1.0 - alpha_a) * grad2 - (1.0 - alpha_b) * grad3
    grad1 = -alpha_a * grad2 - alpha_b * grad3
    corner = (-cloth.bend_stiffness * theta)[..., None, None] * torch.stack([grad0, grad1, grad2, grad3], dim=-2)
    return torch.zeros_like(x).index_add_(-2, cloth.hinges.reshape(-1), corner.flatten(-3, -2))
