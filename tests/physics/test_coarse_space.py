"""The coarse level of the two-level preconditioner: P (Pᵀ K P)⁻¹ Pᵀ against dense algebra (float64)."""

from dataclasses import replace

import numpy as np
import pytest
import torch
from majorant_reference import face_blocks

from physdrape.geometry import topology
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet, open_cylinder
from physdrape.physics import Cloth
from physdrape.physics.coarse_factor import REGULARIZATION
from physdrape.physics.coarse_space import CoarseSpace
from physdrape.physics.forces import extra_blocks, links
from physdrape.physics.layers import LayerOrder
from physdrape.physics.stitches import Stitches


def _batch(sheets: int = 1):
    """A sheet and a tube, then `sheets` − 1 more of the same sheet (one topology: formed together)."""
    sheet = Garment.from_mesh(*grid_sheet(12, 10, width=0.4, height=0.3), name="sheet", dtype=torch.float64)
    tube = Garment.from_mesh(*open_cylinder(6, 14, radius=0.12, length=0.3), name="tube", dtype=torch.float64)
    batch = GarmentBatch.pack([sheet, tube] + [sheet] * (sheets - 1))
    gen = torch.Generator().manual_seed(0)
    x = batch.rest * 1.05 + 3e-3 * torch.randn(batch.rest.shape, generator=gen, dtype=torch.float64)
    return batch, Cloth.build(batch), x


def _dense_prolongation(batch, levels=2, smoothing=2):
    parts = []
    for g in batch.garments:
        edges = topology.undirected_edges(g.faces.numpy())
        label = topology.aggregates(edges, g.num_verts, levels)
        parts.append(topology.smoothed_prolongation(edges, g.num_verts, label, smoothing).toarray())
    rows = sum(p.shape[0] for p in parts)
    out, r, c = np.zeros((rows, sum(p.shape[1] for p in parts))), 0, 0
    for p in parts:
        out[r:r + p.shape[0], c:c + p.shape[1]] = p
        r, c = r + p.shape[0], c + p.shape[1]
    return np.kron(out, np.eye(3)), [p.shape[1] for p in parts]


def _dense_stiffness(x, cloth, extra):
    """K: the faces' majorant blocks, `extra` on the diagonal (with `extra_blocks`, the links'
    diagonal blocks H), and each link's coupling −H between its two vertices."""
    n = 3 * cloth.num_verts
    k = np.zeros((n, n))
    blocks = face_blocks(x, cloth).numpy()
    for f, face in enumerate(cloth.faces.numpy()):
        dof = (3 * face[:, None] + np.arange(3)).reshape(-1)
        k[np.ix_(dof, dof)] += blocks[f]
    for v in range(cloth.num_verts):
        k[3 * v:3 * v + 3, 3 * v:3 * v + 3] += extra[v].numpy()
    tied = links(cloth)
    for (a, b), h in zip(tied.pairs.tolist(), tied.blocks.numpy()) if tied is not None else ():
        k[3 * a:3 * a + 3, 3 * b:3 * b + 3] -= h
        k[3 * b:3 * b + 3, 3 * a:3 * a + 3] -= h
    return k


def _contact_blocks(num_verts, seed=1):
    """Random rank-1 contact-like blocks k n nᵀ (they pin the rigid motions)."""
    gen = torch.Generator().manual_seed(seed)
    normal = torch.nn.functional.normalize(torch.randn(num_verts, 3, generator=gen, dtype=torch.float64), dim=-1)
    return 40.0 * torch.rand(num_verts, generator=gen, dtype=torch.float64)[:, None, None] * normal[:, :, None] * normal[:, None, :]


def _linked(cloth, batch):
    """The cloth with stitches inside the sheet and layer pairs inside the tube."""
    gen = torch.Generator().manual_seed(3)
    sheet_verts, tube_verts = batch.garments[0].num_verts, batch.garments[1].num_verts
    stitched = torch.randperm(sheet_verts, generator=gen)[:16].reshape(8, 2)
    layered = sheet_verts + torch.randperm(tube_verts, generator=gen)[:20].reshape(10, 2)
    normal = torch.nn.functional.normalize(torch.randn(10, 3, generator=gen, dtype=torch.float64), dim=-1)
    return replace(cloth, stitches=Stitches(stitched, torch.full((8,), 0.01, dtype=torch.float64),
                                            torch.full((8,), 200.0, dtype=torch.float64)),
                   layers=LayerOrder.build(layered, normal))


@pytest.mark.parametrize("linked", [False, True], ids=["faces", "faces_and_links"])
@pytest.mark.parametrize("sheets", [1, 3], ids=["topologies", "a_topology_thrice"])
def test_coarse_correction_equals_the_dense_galerkin_solve_per_garment(linked, sheets):
    batch, cloth, x = _batch(sheets)
    gen = torch.Generator().manual_seed(1)
    extra = _contact_blocks(cloth.num_verts)
    if linked:
        cloth = _linked(cloth, batch)
        extra = extra + extra_blocks(cloth)
    coarse = CoarseSpace(cloth)
    coarse.factor(x, extra)
    r = torch.randn(cloth.num_verts, 3, generator=gen, dtype=torch.float64)
    z = coarse.solve(r)
    p, sizes = _dense_prolongation(batch)
    k = _dense_stiffness(x, cloth, extra)
    expected, c0 = np.zeros(3 * cloth.num_verts), 0
    for size in sizes:  # garment by garment, each with its own regularisation
        cols = slice(3 * c0, 3 * (c0 + size))
        kc = p[:, cols].T @ k @ p[:, cols]
        kc += REGULARIZATION * np.diag(kc).mean() * np.eye(3 * size)
        expected += p[:, cols] @ np.linalg.solve(kc, p[:, cols].T @ r.numpy().reshape(-1))
        c0 += size
    assert coarse.num_patches == sum(sizes)
    np.testing.assert_allclose(z.numpy().reshape(-1), expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())
    # the fine-level K it projected, applied to a field: the dense K's product
    product = k @ r.numpy().reshape(-1)
    np.testing.assert_allclose(coarse.stiffness_product(r).numpy().reshape(-1), product, rtol=1e-10,
                               atol=1e-12 * np.abs(product).max())


def test_the_band_factorisation_equals_the_dense_one_and_the_patches_make_a_narrow_band():
    """The CPU factorises each garment's coarse matrix in band storage (LAPACK), CUDA the dense
    matrix: on the same batch (with links) both give the same correction, and the patches are
    numbered so that the band is narrower than the matrix (or the band would gain nothing)."""
    from physdrape.physics.coarse_space import (
        _BatchStructure,
        _galerkin_operator,
        _garment_prolongation,
    )

    batch, cloth, x = _batch()
    cloth = _linked(cloth, batch)
    extra = _contact_blocks(cloth.num_verts) + extra_blocks(cloth)
    band = CoarseSpace(cloth)
    assert band._s.banded
    dense = CoarseSpace(cloth)
    tied = links(cloth).pairs.numpy()
    counts = [tuple(torch.bincount(owner, minlength=cloth.num_garments).tolist())
              for owner in (cloth.vert_garment, cloth.face_garment)]
    dense._s = _BatchStructure.build(cloth.faces.numpy(), *counts, tied, 2, 2, cloth.device, banded=False)
    r = torch.randn(cloth.num_verts, 3, generator=torch.Generator().manual_seed(4), dtype=torch.float64)
    for coarse in (band, dense):
        coarse.factor(x, extra)
    expected = dense.solve(r)
    torch.testing.assert_close(band.solve(r), expected, rtol=1e-9, atol=1e-12 * float(expected.abs().max()))
    # a batch that repeats a garment: dense storage factorises and solves its copies together
    sheet, tube = batch.garments
    repeated = GarmentBatch.pack([sheet, tube, sheet])
    cloth3 = Cloth.build(repeated)
    x3 = torch.cat([x[:sheet.num_verts], x[sheet.num_verts:], 1.02 * x[:sheet.num_verts]])
    counts = [tuple(torch.bincount(owner, minlength=3).tolist()) for owner in (cloth3.vert_garment, cloth3.face_garment)]
    together = CoarseSpace(cloth3)
    together._s = _BatchStructure.build(cloth3.faces.numpy(), *counts, np.zeros((0, 2), np.int64), 2, 2,
                                        cloth3.device, banded=False)
    assert [g.coarse_dofs.shape[0] for g in together._s.groups] == [2, 1]
    apart = CoarseSpace(cloth3)
    contact = _contact_blocks(cloth3.num_verts)
    for coarse in (together, apart):
        coarse.factor(x3, contact)
    r3 = torch.randn(cloth3.num_verts, 3, generator=torch.Generator().manual_seed(5), dtype=torch.float64,
                     requires_grad=True)
    z3 = together.solve(r3)
    torch.testing.assert_close(z3, apart.solve(r3), rtol=1e-9, atol=1e-12 * float(z3.abs().max()))
    weights = torch.randn_like(z3)
    [grad] = torch.autograd.grad((z3 * weights).sum(), r3)  # the correction is symmetric: C w
    torch.testing.assert_close(grad, together.solve(weights), rtol=1e-9, atol=1e-12 * float(grad.abs().max()))
    # a sheet whose vertices are numbered at random, as a garment file may number them
    verts, faces = grid_sheet(40, 30, width=0.8, height=0.6)
    order = np.random.default_rng(0).permutation(len(verts))
    new_id = np.argsort(order)
    sheet = Garment.from_mesh(verts[order], new_id[faces], dtype=torch.float64)
    structure = CoarseSpace(Cloth.build(sheet))._s
    [(c0, c1)], [width] = structure.coarse_ranges, structure.band_widths
    faces = sheet.faces.numpy()
    pairs = np.unique(np.repeat(faces, 3, axis=1).reshape(-1) * sheet.num_verts + np.tile(faces, (1, 3)).reshape(-1))
    patches = _garment_prolongation(faces, sheet.num_verts, 2, 2)
    _, blocks = _galerkin_operator(patches, pairs // sheet.num_verts, pairs % sheet.num_verts)
    as_aggregated = 3 * np.abs(blocks // patches.shape[1] - blocks % patches.shape[1]).max() + 2
    assert c1 - c0 > 150 and width < min(as_aggregated, c1 - c0) / 3, (width, as_aggregated, c1 - c0)


def test_coarse_correction_and_stiffness_product_are_differentiable_and_need_a_factor():
    _, cloth, x = _batch()
    coarse = CoarseSpace(cloth)
    for apply in (coarse.solve, coarse.stiffness_product):
        with pytest.raises(RuntimeError, match="factor"):
            apply(torch.zeros(cloth.num_verts, 3, dtype=torch.float64))
    coarse.factor(x)
    v = torch.randn(cloth.num_verts, 3, dtype=torch.float64)
    for apply in (coarse.solve, coarse.stiffness_product):
        r = torch.randn(cloth.num_verts, 3, dtype=torch.float64, requires_grad=True)
        (apply(r) * v).sum().backward()
        torch.testing.assert_close(r.grad, apply(v))  # a symmetric linear map: its own adjoint


def test_fit_is_the_least_squares_fit_by_the_patches_and_is_differentiable():
    batch, cloth, _ = _batch()
    space = CoarseSpace(cloth)
    dense, _ = _dense_prolongation(batch)
    field = torch.randn(cloth.num_verts, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(3))
    want = dense @ np.linalg.lstsq(dense, field.reshape(-1).numpy(), rcond=None)[0]
    got = space.fit(field)
    np.testing.assert_allclose(got.reshape(-1).numpy(), want, atol=1e-10)
    assert float((field - got).norm()) > 0.5 * float(field.norm())  # a noise field is mostly not smooth
    torch.testing.assert_close(space.fit(got), got)  # a projection: the fit of a fit is itself
    assert space.fit(field.float()).dtype == torch.float32
    assert torch.autograd.gradcheck(space.fit, (field[:, :1].expand(-1, 3).clone().requires_grad_(True),))


def test_coarse_space_checks_its_arguments():
    batch, cloth, _ = _batch()
    with pytest.raises(ValueError, match="levels"):
        CoarseSpace(cloth, levels=0)
    across = Stitches(torch.tensor([[0, batch.num_verts - 1]]), torch.zeros(1, dtype=torch.float64),
                      torch.ones(1, dtype=torch.float64))
    with pytest.raises(ValueError, match="ties two garments"):
        CoarseSpace(replace(cloth, stitches=across))


def test_stitched_pieces_slide_together_as_freely_as_one():
    """Two sheets 5 mm apart, one garment, stitched vertex to vertex with stitches a thousand times
    stiffer than the weak springs that hold every vertex in place: a uniform force moves them
    together, and the stitches must not resist that (only the pieces' relative motion is
    theirs). A stitch's stiffness on the diagonal alone would act as a spring to a fixed point
    and shrink the move about a thousandfold."""
    verts, faces = grid_sheet(8, 8, width=0.2, height=0.2)
    lower = verts + np.array([0.0, -0.005, 0.0])
    two = Garment.from_mesh(np.concatenate([verts, lower]), np.concatenate([faces, faces + len(verts)]),
                            name="two sheets", dtype=torch.float64)
    cloth = Cloth.build(two)
    x = two.rest.clone()
    held = 1.0 * torch.eye(3, dtype=torch.float64).expand(cloth.num_verts, 3, 3)  # 1 N/m per vertex
    pairs = torch.stack([torch.arange(len(verts)), torch.arange(len(verts)) + len(verts)], dim=1)
    stitched = replace(cloth, stitches=Stitches(pairs, torch.full((len(pairs),), 0.005, dtype=torch.float64),
                                                torch.full((len(pairs),), 1000.0, dtype=torch.float64)))
    force = torch.tensor([0.0, 0.0, -1e-3], dtype=torch.float64).expand(cloth.num_verts, 3)
    moves = []
    for c in (cloth, stitched):
        coarse = CoarseSpace(c)
        coarse.factor(x, held + (0.0 if c.stitches is None else extra_blocks(c)))
        moves.append(coarse.solve(force))
    free, tied = moves
    assert float(free[:, 2].mean()) < -5e-4  # not vacuous: the weak springs let the sheets move ~1 mm
    torch.testing.assert_close(tied, free, rtol=0.01, atol=0.01 * float(free.abs().max()))


def test_a_float32_batch_gets_the_float64_correction_to_float32_precision():
    batch, cloth, x = _batch()
    extra = _contact_blocks(cloth.num_verts)
    reference = CoarseSpace(cloth)
    reference.factor(x, extra)
    single = CoarseSpace(Cloth.build(batch.to(torch.float32)))
    single.factor(x.float(), extra.float())
    r = torch.randn(cloth.num_verts, 3, dtype=torch.float64)
    z = single.solve(r.float())
    assert z.dtype == torch.float32
    torch.testing.assert_close(z.double(), reference.solve(r), rtol=1e-3, atol=1e-4 * reference.solve(r).abs().max().item())


def test_an_indefinite_coarse_matrix_is_regularised_until_it_factorises():
    from physdrape.physics.coarse_factor import regularized_cholesky

    block = torch.diag(torch.tensor([1.0, 2.0, -1e-4], dtype=torch.float64))  # a rounded-negative rigid mode
    chol = regularized_cholesky(block.clone())  # it overwrites its argument's diagonal
    rebuilt = chol @ chol.T
    assert torch.isfinite(chol).all() and torch.linalg.eigvalsh(rebuilt).min() > 0
    assert (rebuilt - block).abs().max() < 0.1  # the smallest regularisation that works (1e-4 x mean diag)
    with pytest.raises(ValueError, match="NaN"):
        regularized_cholesky(torch.full((3, 3), float("nan"), dtype=torch.float64))
    # a batch: each matrix keeps the factor of the smallest regularisation that works for it
    definite = torch.diag(torch.tensor([1.0, 2.0, 3.0], dtype=torch.float64))
    both = regularized_cholesky(torch.stack([definite, block]))
    torch.testing.assert_close(both[1], chol)
    assert (both[0] @ both[0].T - definite).abs().max() < 1e-5  # the first try's 1e-6 x mean diag


def test_a_large_garment_is_coarsened_further_to_keep_the_coarse_factor_small():
    from physdrape.physics.coarse_space import MAX_PATCHES

    sheet = Garment.from_mesh(*grid_sheet(90, 90, width=1.0, height=1.0), dtype=torch.float64)  # 8,100 vertices
    edges = topology.undirected_edges(sheet.faces.numpy())
    assert topology.aggregates(edges, sheet.num_verts, 2).max() + 1 > MAX_PATCHES  # not vacuous
    coarse = CoarseSpace(Cloth.build(sheet))
    assert MAX_PATCHES / 5 < coarse.num_patches <= MAX_PATCHES


def test_a_lone_free_patch_factorises():
    """A single triangle at rest, out of contact, has no coarse stiffness at all (its one patch
    moves rigidly at no cost): the factor still exists and the correction is finite."""
    tri = Garment.from_mesh(np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.0], [0.0, 0.05, 0.0]]), np.array([[0, 1, 2]]),
                            name="triangle", dtype=torch.float64)
    batch = GarmentBatch.pack([tri])
    cloth = Cloth.build(batch)
    coarse = CoarseSpace(cloth, levels=2, smoothing=2)
    coarse.factor(batch.rest.clone(), None)
    force = torch.tensor([[0.0, -1e-3, 0.0]] * 3, dtype=torch.float64)
    correction = coarse.solve(force)
    assert torch.isfinite(correction).all() and float((correction * force).sum()) > 0  # a descent direction


def test_batches_of_one_topology_share_their_structure_and_no_other():
    batch, cloth, x = _batch()
    first, again = CoarseSpace(cloth), CoarseSpace(Cloth.build(batch.to(torch.float32)))
    assert first._s is again._s  # the topology is all it depends on (not the dtype or material)
    sheet, tube = batch.garments
    swapped = CoarseSpace(Cloth.build(GarmentBatch.pack([tube, sheet])))
    assert swapped._s is not first._s
    assert CoarseSpace(cloth, smoothing=1)._s is not first._s
    # a solve after another space of the same topology was factorised elsewhere is unaffected
    r = torch.randn(x.shape, generator=torch.Generator().manual_seed(1), dtype=x.dtype)
    first.factor(x)
    expected = first.solve(r)
    again.factor(x.float() * 1.1)
    torch.testing.assert_close(first.solve(r), expected, rtol=0, atol=0)


def test_pair_blocks_given_factorise_as_those_formed_and_refactoring_forms_afresh():
    """A solver's pair blocks (its local terms' buffer) serve as K's storage in place; the coarse
    matrices' storage is reused from one factorisation to the next, each formed afresh."""
    from physdrape.physics.majorant import pair_blocks

    _, cloth, x = _batch(sheets=2)
    extra = _contact_blocks(cloth.num_verts)
    r = torch.randn(x.shape, generator=torch.Generator().manual_seed(3), dtype=x.dtype)
    formed, given = CoarseSpace(cloth), CoarseSpace(cloth)
    formed.factor(x, extra)
    layout, count = given.pair_layout
    given.factor(x * 1.02, extra)  # a factorisation before: its matrices must not linger
    given.factor(x, extra, pair_blocks(x, cloth, layout, count))
    torch.testing.assert_close(given.solve(r), formed.solve(r), rtol=1e-10, atol=0)
    torch.testing.assert_close(given.stiffness_product(r), formed.stiffness_product(r), rtol=1e-12, atol=0)


def test_the_band_factorisation_and_solve_run_on_one_blas_thread(monkeypatch):
    """The solver brings its own threads; SciPy's LAPACK must not start threads of its own beside
    them (they would take the cores the solver's threads run on)."""
    from scipy.linalg import lapack

    from physdrape.threads import blas_controller as _blas

    seen = []

    def spying(name):
        original = getattr(lapack, name)

        def call(*args, **kwargs):
            seen.append({info["num_threads"] for info in _blas().info() if info["user_api"] == "blas"})
            return original(*args, **kwargs)
        return call

    monkeypatch.setattr(lapack, "dpbtrf", spying("dpbtrf"))
    monkeypatch.setattr(lapack, "dpbtrs", spying("dpbtrs"))
    _, cloth, x = _batch()
    coarse = CoarseSpace(cloth)
    with _blas().limit(limits=2, user_api="blas"):  # a process whose BLAS would use two threads
        coarse.factor(x, _contact_blocks(cloth.num_verts))
        coarse.solve(torch.ones(cloth.num_verts, 3, dtype=torch.float64))
    assert len(seen) == 4 and all(threads == {1} for threads in seen), seen  # two garments: 2 factors, 2 solves


def test_one_blas_thread_while_any_thread_is_inside_and_the_setting_restored_after():
    """Two threads entering and leaving in interleaved order (the garment groups of a batch on two
    threads): one BLAS thread until the last leaves, then the process's own setting again."""
    from physdrape.threads import blas_controller as _blas
    from physdrape.threads import one_blas_thread as _one_blas_thread

    def blas_threads():
        return {info["num_threads"] for info in _blas().info() if info["user_api"] == "blas"}

    with _blas().limit(limits=2, user_api="blas"):
        # the process's own setting: 2 threads, and 1 for a BLAS built without threads that an
        # earlier test's imports may have loaded (scs's bundled OpenBLAS)
        own = blas_threads()
        assert 2 in own
        first, second = _one_blas_thread(), _one_blas_thread()
        first.__enter__()
        assert blas_threads() == {1}
        second.__enter__()
        first.__exit__(None, None, None)  # the first to enter leaves first
        assert blas_threads() == {1}
        second.__exit__(None, None, None)
        assert blas_threads() == own
