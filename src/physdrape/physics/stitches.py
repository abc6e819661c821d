"""Stitches: closures (buttons, a wrap's tie) that keep two garment vertices together.

A stitch ties vertices i and j with a one-sided spring that resists their separating beyond
their rest distance L (where the template has them; a button does not stop the panels from
lying closer):

    E_stitch = Σ_s ½ k_s ReLU(‖x_i − x_j‖ − L_s)²                                   [J]
    f_i = −k_s ReLU(r − L) u,  f_j = −f_i,   r = ‖x_i − x_j‖, u = (x_i − x_j) / r     [N]
    ∇²: the 6×6 block [[H, −H], [−H, H]], H = k_s [(1 − L/r)(I − u uᵀ) + u uᵀ] for r > L, 0 else

H is PSD wherever it is nonzero (r > L), so the exact Hessian serves Newton and the solver's
block Jacobi alike. k_s [N/m] per stitch. Like the grip (`physics.grip`), the term is part of the
garment's energy wherever it is measured (`physics.forces`).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["DEFAULT_STITCH_STIFFNESS", "Stitches", "stitch_blocks", "stitch_energy", "stitch_forces",
           "stitch_pair_blocks"]

#: Stiffness of one stitch [N/m].
DEFAULT_STITCH_STIFFNESS = 200.0


@dataclass(frozen=True)
class Stitches:
    """Stitched vertex pairs of a packed garment batch.

    Attributes:
        pairs: (S, 2) int64 vertex indices (into the batch's ΣV vertices).
        rest: rest distance L_s [m] (S,).
        stiffness: k_s [N/m] (S,).
    """

    pairs: Tensor
    rest: Tensor
    stiffness: Tensor

    def to(self, dtype: torch.dtype | None = None, *, device: torch.device | str | None = None) -> Stitches:
        return Stitches(self.pairs.to(device=device), self.rest.to(device=device, dtype=dtype),
                        self.stiffness.to(device=device, dtype=dtype))

    @staticmethod
    def cat(parts: list[Stitches]) -> Stitches:
        """One set of several (indices already offset into one batch)."""
        return Stitches(*(torch.cat([getattr(p, name) for p in parts]) for name in ("pairs", "rest", "stiffness")))


def _separation(x: Tensor, stitches: Stitches) -> tuple[Tensor, Tensor]:
    """(x_i − x_j (..., S, 3), r = its length (..., S))."""
    d = x[..., stitches.pairs[:, 0], :] - x[..., stitches.pairs[:, 1], :]
    return d, d.norm(dim=-1)


def stitch_energy(x: Tensor, stitches: Stitches) -> Tensor:
    """½ k_s ReLU(r − L)² per stitch [J], x (..., V, 3) → (..., S)."""
    _, r = _separation(x, stitches)
    stretch = (r - stitches.rest.to(x.dtype)).clamp_min(0.0)
    return 0.5 * stitches.stiffness.to(x.dtype) * stretch**2


def stitch_forces(x: Tensor, stitches: Stitches) -> Tensor:
    """f = −∇E_stitch on every vertex [N], x (..., V, 3) → (..., V, 3)."""
    d, r = _separation(x, stitches)
    stretch = (r - stitches.rest.to(x.dtype)).clamp_min(0.0)
    scale = stitches.stiffness.to(x.dtype) * stretch / r.clamp_min(torch.finfo(x.dtype).tiny)
    f = -scale[..., None] * d  # on i; −f on j
    out = torch.zeros_like(x).index_add_(-2, stitches.pairs[:, 0], f)
    return out.index_add_(-2, stitches.pairs[:, 1], -f)


def stitch_pair_blocks(x: Tensor, stitches: Stitches) -> Tensor:
    """H per stitch (S, 3, 3) [N/m] (module docstring): its Hessian is [[H, −H], [−H, H]]; x (V, 3)."""
    d, r = _separation(x, stitches)
    rest = stitches.rest.to(x.dtype)
    taut = r > rest
    u = d / r.clamp_min(torch.finfo(x.dtype).tiny)[:, None]
    uu = u[:, :, None] * u[:, None, :]
    eye = torch.eye(3, dtype=x.dtype, device=x.device)
    slack = torch.where(taut, 1.0 - rest / r.clamp_min(torch.finfo(x.dtype).tiny), torch.zeros_like(r))
    k = torch.where(taut, stitches.stiffness.to(x.dtype), torch.zeros_like(r))
    return k[:, None, None] * (slack[:, None, None] * (eye - uu) + uu)


def stitch_blocks(x: Tensor, stitches: Stitches) -> Tensor:
    """The Hessian's 3×3 diagonal blocks per vertex (V, 3, 3) [N/m]; x (V, 3)."""
    h = stitch_pair_blocks(x, stitches)
    out = torch.zeros(x.shape[0], 3, 3, dtype=x.dtype, device=x.device)
    return out.index_add_(0, stitches.pairs[:, 0], h).index_add_(0, stitches.pairs[:, 1], h)
