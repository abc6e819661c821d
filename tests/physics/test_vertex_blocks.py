"""The block-Jacobi preconditioner: per-vertex 3×3 blocks of a PSD majorant of the Hessian (float64)."""

import torch
from physics_cases import random_rotation

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import grid_sheet
from physdrape.physics import Cloth
from physdrape.physics.hessians import (
    _psd_part_2x2,
    bend_gauss_newton_hessian,
    project_psd,
    strain_hessian,
    vertex_blocks,
)
from physdrape.physics.strain import deformation_gradient, green_strain, stress


def _cloth():
    garment = Garment.from_mesh(*grid_sheet(5, 6, width=0.3, height=0.25))
    return garment, Cloth.build(garment)


def _diagonal_blocks(h: torch.Tensor, elems: torch.Tensor, num_verts: int) -> torch.Tensor:
    """Slow twin: each vertex's 3×3 diagonal block of the assembled element Hessians, by a loop."""
    out = torch.zeros(num_verts, 3, 3, dtype=h.dtype)
    for e in range(elems.shape[0]):
        for a, v in enumerate(elems[e].tolist()):
            out[v] += h[e, 3 * a:3 * a + 3, 3 * a:3 * a + 3]
    return out


def _stress(x, cloth):
    return stress(green_strain(deformation_gradient(x, cloth)), cloth)


def test_psd_part_of_2x2_matches_eigendecomposition():
    gen = torch.Generator().manual_seed(0)
    m = torch.randn(200, 2, 2, generator=gen, dtype=torch.float64)
    s = m + m.transpose(-1, -2)
    s[0] = torch.eye(2, dtype=torch.float64) * 3.0  # repeated eigenvalue
    s[1] = -torch.eye(2, dtype=torch.float64)
    evals = torch.linalg.eigvalsh(s)
    assert (evals[:, 0] < 0).any() and (evals[:, 1] > 0).any()
    torch.testing.assert_close(_psd_part_2x2(s), project_psd(s), rtol=1e-12, atol=1e-12)


def test_blocks_equal_exact_hessian_diagonal_where_stretched():
    garment, cloth = _cloth()
    # a rotated anisotropic stretch with a gentle bend: every face's stress is PSD
    x = garment.rest * torch.tensor([1.12, 1.05, 1.0], dtype=torch.float64)
    x = x + torch.stack([0 * x[:, 0], 0 * x[:, 0], 0.2 * x[:, 0] ** 2], -1)
    x = x @ random_rotation(3).T
    assert (torch.linalg.eigvalsh(_stress(x, cloth))[:, 0] > 0).all()
    exact = _diagonal_blocks(strain_hessian(x, cloth), cloth.faces, cloth.num_verts)
    exact += _diagonal_blocks(bend_gauss_newton_hessian(x, cloth), cloth.hinges, cloth.num_verts)
    fast = vertex_blocks(x, cloth)
    assert exact.abs().max() > 1.0
    torch.testing.assert_close(fast, exact, rtol=1e-10, atol=1e-10 * exact.abs().max().item())


def test_blocks_are_psd_majorants_in_compression():
    garment, cloth = _cloth()
    gen = torch.Generator().manual_seed(1)
    x = garment.rest * torch.tensor([0.8, 1.1, 1.0], dtype=torch.float64)
    x = x + 0.01 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    lowest = torch.linalg.eigvalsh(_stress(x, cloth))[:, 0]
    assert (lowest < 0).sum() > 10  # the test is not vacuous: many faces in compression
    exact = _diagonal_blocks(strain_hessian(x, cloth), cloth.faces, cloth.num_verts)
    assert torch.linalg.eigvalsh(exact).min() < 0  # the exact diagonal is indefinite somewhere
    exact += _diagonal_blocks(bend_gauss_newton_hessian(x, cloth), cloth.hinges, cloth.num_verts)
    fast = vertex_blocks(x, cloth)
    scale = fast.abs().max().item()
    assert torch.linalg.eigvalsh(fast).min() >= -1e-10 * scale
    assert torch.linalg.eigvalsh(fast - exact).min() >= -1e-10 * scale
