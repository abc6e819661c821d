"""Per-element Hessians of the garment energies, and their projection to positive semi-definite.

The physics oracle (`physdrape.physics.oracle`) runs projected Newton: every element's Hessian
is made PSD on its own and the blocks are summed into one sparse matrix. All functions are pure
torch, batched over elements, in the dtype of x (the oracle uses float64).

Degree-of-freedom order inside an element block: vertex-major, ``3 * corner + axis``, with the
corners in the order of ``cloth.faces`` (3 corners, 9 dofs) or ``cloth.hinges`` (4 corners,
12 dofs).

- Strain (StVK): closed form. With F = Ds·Dm⁻¹ = Σ_a x_a w_aᵀ (w_a the rows of Dm⁻¹, corner 0
  taking minus their sum), the energy V·ψ(F) has Hessian V·Σ_{j,l} w_aj w_bl A_{cj,dl} with the
  elasticity tensor A = ∂P/∂F = δ_cd S_lj + μ F_cl F_dj + μ (FFᵀ)_cd δ_jl + λ F_cj F_dl.
  `project="strain_tensor"` makes the 6×6 A PSD before mapping (BᵀAB stays PSD; cheaper than the
  9×9 eigendecomposition and it keeps the exact translation null space).
- Bending: batched forward-over-reverse autograd of the per-hinge energy
  (``torch.func.vmap(torch.func.hessian(...))``), or the Gauss-Newton part k·∇θ∇θᵀ alone
  (PSD by construction, cheap, no curvature of θ).
- The stretching solver's preconditioners use a PSD majorant of the strain Hessian in closed
  form instead (`physdrape.physics.majorant`).
"""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.strain import deformation_gradient, green_strain, stress

__all__ = [
    "bend_gauss_newton_hessian",
    "bend_hessian",
    "project_psd",
    "strain_hessian",
    "strain_stress_tensor",
]


def project_psd(h: Tensor, *, floor: float = 0.0) -> Tensor:
    """Project symmetric matrices to PSD by clamping their eigenvalues at `floor`.

    h: (..., n, n) symmetric → (..., n, n) with eigenvalues ≥ floor (floor ≥ 0).
    """
    h = 0.5 * (h + h.transpose(-1, -2))
    evals, evecs = torch.linalg.eigh(h)
    return (evecs * evals.clamp_min(floor).unsqueeze(-2)) @ evecs.transpose(-1, -2)


def _corner_weights(cloth: Cloth) -> Tensor:
    """w (F, 3 corners, 2): F = Σ_a x_a ⊗ w_a, from Dm⁻¹ (rows 0, 1 for corners 1, 2)."""
    r = cloth.rest_inv
    return torch.stack([-(r[:, 0] + r[:, 1]), r[:, 0], r[:, 1]], dim=1)


def strain_stress_tensor(x: Tensor, cloth: Cloth) -> Tensor:
    """Elasticity tensor A = ∂P/∂F of StVK per face, x (V, 3) → (F, 6, 6), index 2·c + j of F[c, j].

    Units: Pa (P = ∂ψ/∂F, ψ an energy per volume).
    """
    F = deformation_gradient(x, cloth)  # (F, 3, 2)
    mu, lam = cloth.mu[:, None, None, None, None], cloth.lam[:, None, None, None, None]
    eye2 = torch.eye(2, dtype=x.dtype, device=x.device)
    eye3 = torch.eye(3, dtype=x.dtype, device=x.device)
    S = stress(green_strain(F), cloth)  # (F, 2, 2)
    FFt = F @ F.transpose(-1, -2)  # (F, 3, 3)
    t1 = eye3[None, :, None, :, None] * S[:, None, :, None, :]  # δ_cd S_jl
    t2 = mu * torch.einsum("fcl,fdj->fcjdl", F, F)  # μ F_cl F_dj
    t3 = mu * FFt[:, :, None, :, None] * eye2[None, None, :, None, :]  # μ (FFᵀ)_cd δ_jl
    t4 = lam * torch.einsum("fcj,fdl->fcjdl", F, F)  # λ F_cj F_dl
    A = t1 + t2 + t3 + t4
    return A.reshape(-1, 6, 6)


def strain_hessian(x: Tensor, cloth: Cloth, *, project: bool = False, floor: float = 0.0) -> Tensor:
    """Hessian of each face's StVK energy w.r.t. its 3 corners, x (V, 3) → (F, 9, 9) [J/m²].

    project=True clamps the eigenvalues of the 6×6 elasticity tensor at `floor` first, which makes
    every block PSD (the mapping F ↦ x is linear).
    """
    A = strain_stress_tensor(x, cloth)
    if project:
        A = project_psd(A, floor=floor)
    A = A.reshape(-1, 3, 2, 3, 2)
    w = _corner_weights(cloth)  # (F, 3, 2)
    H = torch.einsum("faj,fbl,fcjdl->facbd", w, w, A) * cloth.volume[:, None, None, None, None]
    return H.reshape(-1, 9, 9)


def _hinge_energy(xs: Tensor, stiffness: Tensor) -> Tensor:
    """One hinge's bending energy, xs (4, 3) [m], stiffness k·l₀²/(4(A₀+A₁)) [J] → scalar [J]."""
    x0, x1, x2, x3 = xs[0], xs[1], xs[2], xs[3]
    edge = x1 - x0
    n_a = torch.linalg.cross(edge, x2 - x0)
    n_b = torch.linalg.cross(x3 - x0, edge)
    sin_term = (torch.linalg.cross(n_a, n_b) * edge).sum() / edge.norm()
    theta = torch.atan2(sin_term, (n_a * n_b).sum())
    return 0.5 * stiffness * theta * theta


_hinge_hessian = torch.func.vmap(torch.func.hessian(_hinge_energy))


def bend_hessian(x: Tensor, cloth: Cloth, *, project: bool = False, floor: float = 0.0) -> Tensor:
    """Hessian of each hinge's bending energy w.r.t. its 4 vertices, x (V, 3) → (H, 12, 12) [J/m²].

    Batched autograd (forward-over-reverse); project=True clamps each 12×12 block's eigenvalues.
    """
    xs = x[cloth.hinges]  # (H, 4, 3)
    H = _hinge_hessian(xs, cloth.bend_stiffness).reshape(-1, 12, 12)
    return project_psd(H, floor=floor) if project else H


def _angle_gradients(x: Tensor, cloth: Cloth) -> Tensor:
    """∇θ of each hinge's dihedral angle w.r.t. its 4 vertices, x (V, 3) → (H, 4, 3) [1/m];
    closed form, as in `physdrape.physics.bending.bend_forces`."""
    h = cloth.hinges
    x0, x1, x2, x3 = (x[h[:, k]] for k in range(4))
    edge = x1 - x0
    n_a = torch.linalg.cross(edge, x2 - x0)
    n_b = torch.linalg.cross(x3 - x0, edge)
    edge_sq = (edge * edge).sum(-1)
    edge_len = edge_sq.sqrt()
    grad2 = -(edge_len / (n_a * n_a).sum(-1))[:, None] * n_a
    grad3 = -(edge_len / (n_b * n_b).sum(-1))[:, None] * n_b
    alpha_a = (((x2 - x0) * edge).sum(-1) / edge_sq)[:, None]
    alpha_b = (((x3 - x0) * edge).sum(-1) / edge_sq)[:, None]
    grad0 = -(1.0 - alpha_a) * grad2 - (1.0 - alpha_b) * grad3
    grad1 = -alpha_a * grad2 - alpha_b * grad3
    return torch.stack([grad0, grad1, grad2, grad3], dim=1)


def bend_gauss_newton_hessian(x: Tensor, cloth: Cloth) -> Tensor:
    """Gauss-Newton bending Hessian k·∇θ∇θᵀ per hinge, x (V, 3) → (H, 12, 12) [J/m²]; PSD."""
    g = _angle_gradients(x, cloth).reshape(-1, 12)
    return cloth.bend_stiffness[:, None, None] * g[:, :, None] * g[:, None, :]
