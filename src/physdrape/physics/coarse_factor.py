"""Factorising and solving the coarse level's matrices (`physics.coarse_space`): each garment's
Pᵀ K P by Cholesky, dense (a batch of them at once, on any device) or in band storage on the CPU
(LAPACK's pbtrf and pbtrs), regularised until it factorises, and the band solve, differentiable in
its right-hand side."""

from __future__ import annotations

import numpy as np
import torch
from scipy.linalg import lapack
from torch import Tensor

from physdrape.threads import one_blas_thread

__all__ = ["REGULARIZATION", "BandSolve", "regularized_band_cholesky", "regularized_cholesky"]

#: Regularisation of Pᵀ K P relative to its mean diagonal (a garment the contact does not pin);
#: raised ×100 until the factorisation succeeds.
REGULARIZATION = 1e-6


def _regularized(matrix: Tensor, diagonal: Tensor, factorise):
    """factorise() of symmetric matrices after adding r·mean(diag) to each one's diagonal, r =
    REGULARIZATION raised ×100 until it factorises (a float32 K rounds its near-null rigid modes to
    slightly negative), each matrix keeping the factor of the smallest r that worked; factorise
    returns the factors and whether each worked (a bool per matrix, or one for a single matrix). A
    matrix without stiffness (a garment of one patch, free of the body, moves rigidly at no cost)
    is regularised with mean(diag) = 1: its correction is then a long rigid move that the solver's
    step clip and line search shorten like any other. `matrix` holds the entries (dense or band
    storage, with `diagonal` (..., n) a view of the diagonals); it is a scratch copy: its
    diagonals are overwritten. Dense matrices may come as a batch (count, n, n)."""
    if not bool(torch.isfinite(matrix.sum())):  # a sum is finite only if every entry is
        raise ValueError("CoarseSpace.factor: the stiffness has NaN/inf entries (non-finite positions?)")
    original = diagonal.clone()
    scale = original.mean(-1, keepdim=True)
    # no stiffness at all (a lone patch moving freely): any scale regularises it
    scale = torch.where(scale > 0, scale, torch.ones_like(scale))
    best = done = None
    for attempt in range(4):  # up to REGULARIZATION × 10⁶ = the mean diagonal itself
        diagonal.copy_(original + REGULARIZATION * 100.0 ** attempt * scale)
        factor, ok = factorise()
        ok = torch.as_tensor(ok, device=matrix.device)
        if best is None or not torch.is_tensor(factor):  # the first try, or a single band matrix
            best, done = factor, ok
        else:  # the matrices that factorised before keep their factor
            best, done = torch.where(done[..., None, None], best, factor), done | ok
        if bool(done.all()):
            return best
    raise ValueError("CoarseSpace.factor: the coarse stiffness is not positive semi-definite even with a "
                     "regularisation of its mean diagonal (K must be a PSD majorant)")


def regularized_cholesky(blocks: Tensor) -> Tensor:
    """Dense Cholesky factors L (count, n, n) of regularised (`_regularized`) blocks (count, n, n),
    on any device, in one batched factorisation."""
    def factorise():
        chol, info = torch.linalg.cholesky_ex(blocks)
        return chol, info == 0

    return _regularized(blocks, blocks.diagonal(dim1=-2, dim2=-1), factorise)


def regularized_band_cholesky(band: Tensor) -> np.ndarray:
    """Band Cholesky factor (LAPACK pbtrf, lower) of a regularised (`_regularized`) symmetric band
    matrix given as band (n, w + 1) on the CPU, band[j, k] = A[j + k, j] (zero past the end):
    returned as LAPACK's (w + 1, n) band storage, what `BandSolve` reads."""
    lower = band.numpy().T  # (w + 1, n), Fortran order: LAPACK's storage without a copy

    def factorise():
        chol, info = lapack.dpbtrf(lower, lower=1)
        return chol, info == 0

    return _regularized(band, band[:, 0], factorise)


def _band_solve(rhs: Tensor, factors: list[np.ndarray], ranges: list[tuple[int, int]]) -> Tensor:
    """A⁻¹ rhs (C, 1) float64 on the CPU for the block-diagonal A of the garments' band factors."""
    out = torch.empty_like(rhs)
    values = rhs.detach().numpy()
    with one_blas_thread():
        for (c0, c1), chol in zip(ranges, factors):
            out[c0:c1] = torch.from_numpy(lapack.dpbtrs(chol, values[c0:c1], lower=1)[0])
    return out


class BandSolve(torch.autograd.Function):
    """`_band_solve`, differentiable in rhs (A is symmetric: the backward is the same solve)."""

    @staticmethod
    def forward(ctx, rhs: Tensor, factors: list, ranges: list) -> Tensor:
        ctx.factors, ctx.ranges = factors, ranges
        return _band_solve(rhs, factors, ranges)

    @staticmethod
    def backward(ctx, grad: Tensor):
        return _band_solve(grad.contiguous(), ctx.factors, ctx.ranges), None, None
