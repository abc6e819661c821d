"""Slow twins of `physdrape.physics.majorant` in plain torch (the reference its Warp kernels are
tested against): the PSD strain-Hessian majorant per face and its per-vertex diagonal with
Gauss-Newton bending, in the dtype of x."""

import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.hessians import _angle_gradients, _corner_weights
from physdrape.physics.strain import deformation_gradient, green_strain, stress


def _abs_part_2x2(S: Tensor) -> Tensor:
    """|S| of symmetric 2×2 matrices (eigenvalues replaced by their absolute values), (..., 2, 2),
    closed form."""
    a, b, d = S[..., 0, 0], S[..., 0, 1], S[..., 1, 1]
    mean, half = 0.5 * (a + d), (0.25 * (a - d) ** 2 + b * b).sqrt()
    lo, hi = mean - half, mean + half
    # S = hi·P + lo·(I − P) with P the projector on the top eigenvector: |S| = |hi| P + |lo| (I − P).
    eye = torch.eye(2, dtype=S.dtype, device=S.device)
    gap = (hi - lo)[..., None, None]
    proj = torch.where(gap > 0, (S - lo[..., None, None] * eye) / gap.clamp_min(torch.finfo(S.dtype).tiny), 0.5 * eye)
    return hi.abs()[..., None, None] * proj + lo.abs()[..., None, None] * (eye - proj)


def _majorant_terms(x: Tensor, cloth: Cloth) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Per face: corner weights w (F, 3, 2), u_a = F w_a (F, 3, 3), |S| (F, 2, 2), F Fᵀ (F, 3, 3)."""
    F = deformation_gradient(x, cloth)  # (F, 3, 2)
    w = _corner_weights(cloth)  # (F, 3, 2)
    u = torch.einsum("fcj,faj->fac", F, w)
    return w, u, _abs_part_2x2(stress(green_strain(F), cloth)), F @ F.transpose(-1, -2)


def face_blocks(x: Tensor, cloth: Cloth) -> Tensor:
    """Each face's 9×9 block of the PSD strain-Hessian majorant (`physdrape.physics.majorant`), x (V, 3) →
    (F, 9, 9) [N/m], dof order 3·corner + axis as `strain_hessian`, which it equals on faces
    whose stress is PSD."""
    w, u, s_abs, FFt = _majorant_terms(x, cloth)
    eye3 = torch.eye(3, dtype=x.dtype, device=x.device)
    mu, lam = cloth.mu[:, None, None, None, None], cloth.lam[:, None, None, None, None]
    wsw = torch.einsum("faj,fjl,fbl->fab", w, s_abs, w)
    ww = torch.einsum("faj,fbj->fab", w, w)
    block = (wsw[..., None, None] * eye3 + mu * u[:, None, :, :, None] * u[:, :, None, None, :]
             + lam * u[:, :, None, :, None] * u[:, None, :, None, :] + mu * ww[..., None, None] * FFt[:, None, None])
    block = cloth.volume[:, None, None, None, None] * block  # (F, a, b, c, d)
    return block.permute(0, 1, 3, 2, 4).reshape(-1, 9, 9)


def vertex_blocks(x: Tensor, cloth: Cloth) -> Tensor:
    """3×3 diagonal blocks per vertex of a PSD majorant of ∇²(E_strain + E_bend) (`physdrape.physics.majorant`).

    x (V, 3) [m] → (V, 3, 3) [N/m], symmetric PSD. The strain part equals the diagonal blocks of
    `strain_hessian` wherever every face's stress S is PSD; the bending part is Gauss-Newton.
    """
    w, u, s_abs, FFt = _majorant_terms(x, cloth)
    eye3 = torch.eye(3, dtype=x.dtype, device=x.device)
    sws = torch.einsum("faj,fjl,fal->fa", w, s_abs, w)
    ww = (w * w).sum(-1)
    block = (sws[..., None, None] * eye3 + (cloth.mu + cloth.lam)[:, None, None, None] * u[..., :, None] * u[..., None, :]
             + (cloth.mu[:, None] * ww)[..., None, None] * FFt[:, None])
    block = cloth.volume[:, None, None, None] * block
    out = torch.zeros(cloth.num_verts, 3, 3, dtype=x.dtype, device=x.device)
    out.index_add_(0, cloth.faces.reshape(-1), block.reshape(-1, 3, 3))
    g = _angle_gradients(x, cloth)  # (H, 4, 3)
    bend = cloth.bend_stiffness[:, None, None, None] * g[..., :, None] * g[..., None, :]
    return out.index_add_(0, cloth.hinges.reshape(-1), bend.reshape(-1, 3, 3))
