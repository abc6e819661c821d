"""The preconditioners' blocks (`physdrape.physics.majorant`, Warp kernels): per-face 9×9 and
per-vertex 3×3 blocks of a PSD majorant of the Hessian (float64), against the exact Hessians and
against their plain-torch twins."""

import pytest
import torch
from majorant_reference import _abs_part_2x2
from majorant_reference import face_blocks as reference_face_blocks
from majorant_reference import vertex_blocks as reference_vertex_blocks
from physics_cases import random_rotation

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import grid_sheet
from physdrape.physics import Cloth
from physdrape.physics.hessians import (
    bend_gauss_newton_hessian,
    strain_hessian,
)
from physdrape.physics.majorant import pair_blocks, vertex_blocks, vertex_compliance
from physdrape.physics.strain import deformation_gradient, green_strain, stress


def _cloth():
    garment = Garment.from_mesh(*grid_sheet(5, 6, width=0.3, height=0.25))
    return garment, Cloth.build(garment)


def face_blocks(x: torch.Tensor, cloth: Cloth) -> torch.Tensor:
    """Every face's 9×9 block from `pair_blocks` with one pair per face corner pair, (F, 9, 9)."""
    num_faces = cloth.faces.shape[0]
    pairs = torch.arange(9 * num_faces, dtype=torch.int32).reshape(num_faces, 9)
    blocks = pair_blocks(x, cloth, pairs, 9 * num_faces).reshape(num_faces, 3, 3, 3, 3)  # (F, a, b, c, d)
    return blocks.permute(0, 1, 3, 2, 4).reshape(num_faces, 9, 9)


def _diagonal_blocks(h: torch.Tensor, elems: torch.Tensor, num_verts: int) -> torch.Tensor:
    """Slow twin: each vertex's 3×3 diagonal block of the assembled element Hessians, by a loop."""
    out = torch.zeros(num_verts, 3, 3, dtype=h.dtype)
    for e in range(elems.shape[0]):
        for a, v in enumerate(elems[e].tolist()):
            out[v] += h[e, 3 * a:3 * a + 3, 3 * a:3 * a + 3]
    return out


def _stretched(garment):
    """A rotated anisotropic stretch with a gentle bend: every face's stress is PSD."""
    x = garment.rest * torch.tensor([1.12, 1.05, 1.0], dtype=torch.float64)
    x = x + torch.stack([0 * x[:, 0], 0 * x[:, 0], 0.2 * x[:, 0] ** 2], -1)
    return x @ random_rotation(3).T


def _stress(x, cloth):
    return stress(green_strain(deformation_gradient(x, cloth)), cloth)


def test_abs_part_of_2x2_matches_eigendecomposition():
    gen = torch.Generator().manual_seed(0)
    m = torch.randn(200, 2, 2, generator=gen, dtype=torch.float64)
    s = m + m.transpose(-1, -2)
    s[0] = torch.eye(2, dtype=torch.float64) * 3.0  # repeated eigenvalue
    s[1] = -torch.eye(2, dtype=torch.float64)
    evals, evecs = torch.linalg.eigh(s)
    assert (evals[:, 0] < 0).any() and (evals[:, 1] > 0).any()
    expected = (evecs * evals.abs().unsqueeze(-2)) @ evecs.transpose(-1, -2)
    torch.testing.assert_close(_abs_part_2x2(s), expected, rtol=1e-12, atol=1e-12)


def test_blocks_equal_exact_hessian_diagonal_where_stretched():
    garment, cloth = _cloth()
    x = _stretched(garment)
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


def test_face_blocks_equal_exact_hessian_where_stretched():
    garment, cloth = _cloth()
    x = _stretched(garment)
    assert (torch.linalg.eigvalsh(_stress(x, cloth))[:, 0] > 0).all()
    exact = strain_hessian(x, cloth)
    torch.testing.assert_close(face_blocks(x, cloth), exact, rtol=1e-10, atol=1e-10 * exact.abs().max().item())


def test_face_blocks_are_psd_majorants_in_compression_and_share_the_vertex_diagonal():
    garment, cloth = _cloth()
    gen = torch.Generator().manual_seed(2)
    x = garment.rest * torch.tensor([0.8, 1.1, 1.0], dtype=torch.float64)
    x = x + 0.01 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    assert (torch.linalg.eigvalsh(_stress(x, cloth))[:, 0] < 0).sum() > 10
    exact, fast = strain_hessian(x, cloth), face_blocks(x, cloth)
    assert torch.linalg.eigvalsh(exact).min() < 0  # not vacuous: some exact face blocks are indefinite
    scale = fast.abs().max().item()
    assert torch.linalg.eigvalsh(fast).min() >= -1e-10 * scale
    assert torch.linalg.eigvalsh(fast - exact).min() >= -1e-10 * scale
    # the vertex blocks are the diagonal of the face blocks plus Gauss-Newton bending
    diagonal = _diagonal_blocks(fast, cloth.faces, cloth.num_verts)
    diagonal += _diagonal_blocks(bend_gauss_newton_hessian(x, cloth), cloth.hinges, cloth.num_verts)
    torch.testing.assert_close(vertex_blocks(x, cloth), diagonal, rtol=1e-10, atol=1e-10 * scale)


@pytest.mark.parametrize("state", ["stretched", "compressed"])
def test_kernels_equal_their_torch_twins(state):
    garment, cloth = _cloth()
    gen = torch.Generator().manual_seed(3)
    x = _stretched(garment) if state == "stretched" else garment.rest * torch.tensor([0.8, 1.1, 1.0],
                                                                                    dtype=torch.float64)
    x = x + 0.005 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    fast, slow = face_blocks(x, cloth), reference_face_blocks(x, cloth)
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12 * slow.abs().max().item())
    fast, slow = vertex_blocks(x, cloth), reference_vertex_blocks(x, cloth)
    torch.testing.assert_close(fast, slow, rtol=1e-12, atol=1e-12 * slow.abs().max().item())


def test_float32_positions_give_float32_blocks_close_to_float64():
    garment, cloth = _cloth()
    x = _stretched(garment)
    cloth32 = Cloth.build(Garment.from_mesh(*grid_sheet(5, 6, width=0.3, height=0.25), dtype=torch.float32))
    blocks = vertex_blocks(x.float(), cloth32)
    assert blocks.dtype == torch.float32
    torch.testing.assert_close(blocks.double(), vertex_blocks(x, cloth), rtol=1e-5, atol=1e-5 * blocks.abs().max().item())


def test_pair_blocks_refuse_a_bad_pair_table():
    garment, cloth = _cloth()
    with pytest.raises(ValueError, match="pair_of_corner must be int32"):
        pair_blocks(garment.rest, cloth, torch.zeros(cloth.faces.shape[0], 9, dtype=torch.int64), 1)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_vertex_compliance_inverts_the_floored_blocks(dtype):
    """(K_i + rel·max(tr K_i, tiny)·I)⁻¹ with K_i the vertex blocks plus extra blocks, against
    LAPACK's inverse in float64, without and with contact-like rank-1 extra blocks."""
    garment, cloth = _cloth()
    gen = torch.Generator().manual_seed(4)
    x = _stretched(garment)
    normal = torch.nn.functional.normalize(torch.randn(cloth.num_verts, 3, generator=gen, dtype=torch.float64), dim=-1)
    extra = 50.0 * torch.rand(cloth.num_verts, generator=gen, dtype=torch.float64)[:, None, None] * (
        normal[:, :, None] * normal[:, None, :])
    rel = 1e-6
    for blocks_extra in (None, extra):
        k = vertex_blocks(x, cloth) + (0.0 if blocks_extra is None else blocks_extra)
        floored = k + rel * k.diagonal(dim1=-2, dim2=-1).sum(-1)[:, None, None] * torch.eye(3, dtype=torch.float64)
        expected = torch.linalg.inv(floored)
        got = vertex_compliance(x.to(dtype), cloth.to(dtype),
                                None if blocks_extra is None else blocks_extra.to(dtype), rel=rel)
        assert got.dtype == dtype
        tol = 1e-8 if dtype == torch.float64 else 1e-3  # float32: x and the extra blocks are rounded first
        torch.testing.assert_close(got.double(), expected, rtol=tol, atol=tol * expected.abs().amax().item())
    with pytest.raises(ValueError, match="extra blocks must have shape"):
        vertex_compliance(x, cloth, extra[:-1], rel=rel)
