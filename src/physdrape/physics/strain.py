"""StVK membrane strain: energy per face and its analytic force (paper Eq. 1).

The energy and force run as Warp kernels (`physics.element_kernels`); the torch helpers here
(F, G, S) serve the oracle's closed-form Hessians (`physics.hessians`)."""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.element_kernels import strain_energy_per_face, strain_force


def deformation_gradient(x: Tensor, cloth: Cloth) -> Tensor:
    """F = Ds · Dm⁻¹ per face, x (..., V, 3) [m] → (..., F, 3, 2)."""
    f = cloth.faces
    x0 = x[..., f[:, 0], :]
    ds = torch.stack([x[..., f[:, 1], :] - x0, x[..., f[:, 2], :] - x0], dim=-1)
    return ds @ cloth.rest_inv


def green_strain(F: Tensor) -> Tensor:
    """Green–Lagrange strain G = ½(FᵀF − I), (..., 3, 2) → (..., 2, 2)."""
    eye = torch.eye(2, dtype=F.dtype, device=F.device)
    return 0.5 * (F.transpose(-1, -2) @ F - eye)


def stress(G: Tensor, cloth: Cloth) -> Tensor:
    """StVK second Piola-Kirchhoff stress S = 2μG + λ tr(G) I [Pa], G (..., F, 2, 2) → (..., F, 2, 2)."""
    trace = G[..., 0, 0] + G[..., 1, 1]
    eye = torch.eye(2, dtype=G.dtype, device=G.device)
    return 2.0 * cloth.mu[:, None, None] * G + (cloth.lam * trace)[..., None, None] * eye


def strain_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_strain per face = t·A·(μ‖G‖²_F + λ/2·tr(G)²) [J], x (..., V, 3) → (..., F).

    Computed by a Warp kernel (`physics.element_kernels`); differentiable in x."""
    return strain_energy_per_face(x, cloth.faces, cloth.rest_inv, cloth.volume, cloth.mu, cloth.lam)


def strain_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_i = −Σ_T V_T P_T b_{i,T} with P = F·S, S = 2μG + λ tr(G) I (paper Eq. 1) [N].

    b_{i,T} are the rows of Dm⁻¹ (corners 1, 2) and minus their sum (corner 0). Equal to
    −∇E_strain; computed by a Warp kernel (`physics.element_kernels`), differentiable in x (its
    backward is the Hessian–vector product). x (..., V, 3) → (..., V, 3).
    """
    return strain_force(x, cloth.faces, cloth.rest_inv, cloth.volume, cloth.mu, cloth.lam)
