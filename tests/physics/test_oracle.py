"""Tests of the physics oracle: element Hessians (float64, against autograd), PSD projection,
projected Newton on small draped tops (monotone energy, no vertex or face centroid inside the
body, convergence),
packed batches, and the optional IPC mode (skipped without ipctk)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
import torch
from element_reference import bend_energy, strain_energy

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet, open_cylinder
from physdrape.geometry.proximity import BodySurface
from physdrape.physics import Cloth, penalty_contact_energy
from physdrape.physics.hessians import (
    bend_gauss_newton_hessian,
    bend_hessian,
    project_psd,
    strain_hessian,
)
from physdrape.physics.oracle import OracleResult, relax

trimesh = pytest.importorskip("trimesh")
HAS_IPCTK = importlib.util.find_spec("ipctk") is not None

#: Body of revolution (radius [m], height y [m]): torso, cone "shoulders", neck, head cap.
BODY_PROFILE = np.array([[0.0, -0.2], [0.16, -0.2], [0.16, 0.2], [0.05, 0.35], [0.05, 0.45], [0.0, 0.45]])


@pytest.fixture(scope="module")
def body():
    """A closed body of revolution about y with cone shoulders.

    A frictionless static drape needs the garment held up by the body. On a sphere or a capsule's
    cap a collar rolls off (every plane section is a circle); on a cone a ring cannot tilt
    without rising, so the drape below is stable.
    """
    mesh = trimesh.creation.revolve(BODY_PROFILE, sections=32)  # about z
    verts = np.asarray(mesh.vertices)[:, [0, 2, 1]] * np.array([1.0, 1.0, -1.0])  # z-axis → y-axis (a rotation)
    return BodySurface(torch.tensor(verts), torch.tensor(np.asarray(mesh.faces)))


def _top(rings=7, segments=24, *, lift=0.005, hem=0.1):
    """A small top (surface of revolution): neck opening, shoulder cone `lift` [m] above the body's,
    then hanging around the torso down to y = hem."""
    profile = np.array([[0.084, 0.312], [0.164, 0.203], [0.175, 0.18], [0.175, hem]])
    profile[:2] += (lift - 0.005) * np.array([0.806, 0.591])  # along the cone's outward normal
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(profile, axis=0), axis=1))])
    s = np.linspace(0.0, arc[-1], rings)
    radius, height = np.interp(s, arc, profile[:, 0]), np.interp(s, arc, profile[:, 1])
    verts, faces = open_cylinder(rings, segments, radius=1.0, length=1.0)
    ring = np.repeat(np.arange(rings), segments)
    verts[:, [0, 2]] *= radius[ring, None]
    verts[:, 1] = height[ring]
    return Garment.from_mesh(verts, faces)


def _random_state(garment, scale, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return garment.rest + scale * torch.randn(garment.rest.shape, generator=gen, dtype=torch.float64)


def _autograd_element_hessian(energy_fn, x, cloth, elems, k):
    """Slow loop twin: the Hessian of element k's energy w.r.t. its own vertices by autograd."""
    idx = elems[k]

    def fn(xs):
        xx = x.clone()
        xx[idx] = xs
        return energy_fn(xx, cloth)[k]

    n = 3 * idx.numel()
    return torch.autograd.functional.hessian(fn, x[idx].clone()).reshape(n, n)


@pytest.fixture(scope="module")
def small_cloth():
    verts, faces = grid_sheet(4, 4, width=0.2, height=0.2)
    garment = Garment.from_mesh(verts, faces)
    return garment, Cloth.build(garment)


def test_strain_hessian_matches_autograd(small_cloth):
    garment, cloth = small_cloth
    x = _random_state(garment, 0.03)
    fast = strain_hessian(x, cloth)
    assert fast.dtype == torch.float64 and fast.shape == (cloth.faces.shape[0], 9, 9)
    for k in range(cloth.faces.shape[0]):
        slow = _autograd_element_hessian(strain_energy, x, cloth, cloth.faces, k)
        assert slow.abs().max() > 1.0  # a non-trivial (non-rest) state
        torch.testing.assert_close(fast[k], slow, rtol=1e-9, atol=1e-9 * slow.abs().max().item())


def test_bend_hessian_matches_autograd(small_cloth):
    garment, cloth = small_cloth
    x = _random_state(garment, 0.03, seed=1)
    fast = bend_hessian(x, cloth)
    assert fast.shape == (cloth.hinges.shape[0], 12, 12)
    for k in range(cloth.hinges.shape[0]):
        slow = _autograd_element_hessian(bend_energy, x, cloth, cloth.hinges, k)
        assert slow.abs().max() > 0
        torch.testing.assert_close(fast[k], slow, rtol=1e-9, atol=1e-9 * slow.abs().max().item())


def test_bend_gauss_newton_hessian_is_outer_product_of_angle_gradient(small_cloth):
    from physdrape.physics import dihedral_angle

    garment, cloth = small_cloth
    x = _random_state(garment, 0.03, seed=4)
    fast = bend_gauss_newton_hessian(x, cloth)
    for k in range(cloth.hinges.shape[0]):
        idx = cloth.hinges[k]

        def theta(xs):
            xx = x.clone()
            xx[idx] = xs
            return dihedral_angle(xx, cloth.hinges)[k]

        grad = torch.autograd.functional.jacobian(theta, x[idx].clone()).reshape(12)
        assert grad.abs().max() > 0
        slow = cloth.bend_stiffness[k] * torch.outer(grad, grad)
        torch.testing.assert_close(fast[k], slow, rtol=1e-9, atol=1e-12 * slow.abs().max().item())


def test_projected_hessians_are_psd(small_cloth):
    garment, cloth = small_cloth
    x = _random_state(garment, 0.05, seed=2)
    raw = bend_hessian(x, cloth)
    assert torch.linalg.eigvalsh(raw).min() < 0  # the test is not vacuous
    for h in (strain_hessian(x, cloth, project=True), bend_hessian(x, cloth, project=True),
              bend_gauss_newton_hessian(x, cloth)):
        evals = torch.linalg.eigvalsh(h)
        assert (evals >= -1e-10 * evals.abs().max()).all()
    # compressed state: the raw strain Hessian is indefinite, the projected one is not
    squeezed = garment.rest * torch.tensor([0.7, 1.0, 0.7], dtype=torch.float64)
    assert torch.linalg.eigvalsh(strain_hessian(squeezed, cloth)).min() < 0


def test_solve_with_held_vertices_matches_dense_reduced_system():
    import scipy.sparse as sp

    from physdrape.physics.oracle.linalg import (
        LinearSolver,
        _diagonal_positions,
        _resolve_solver,
        _solve_fixed,
        _SparseSolver,
    )

    rng = np.random.default_rng(5)
    n_verts = 6
    a = rng.standard_normal((3 * n_verts, 3 * n_verts))
    dense = a @ a.T + 3 * n_verts * np.eye(3 * n_verts)
    lower = sp.csc_matrix(np.tril(dense))
    lower.sort_indices()
    rhs = rng.standard_normal(3 * n_verts)
    fixed = np.array([True, False, False, True, False, False])
    keep = ~np.repeat(fixed, 3)
    expected = np.zeros_like(rhs)
    expected[keep] = np.linalg.solve(dense[np.ix_(keep, keep)], rhs[keep])
    for solver in {_resolve_solver("auto"), LinearSolver.SUPERLU}:
        out = _solve_fixed(lower, _diagonal_positions(lower), rhs, fixed, _SparseSolver(solver))
        np.testing.assert_allclose(out, expected, rtol=1e-10, atol=1e-12)


def test_cholmod_refactors_on_a_repeated_pattern_reanalyses_a_new_one_and_rejects_indefinite():
    pytest.importorskip("cvxopt")
    import scipy.sparse as sp

    from physdrape.physics.oracle.linalg import (
        LinearSolver,
        _diagonal_positions,
        _SparseSolver,
    )

    rng = np.random.default_rng(5)
    solver = _SparseSolver(LinearSolver.CHOLMOD)

    def system(n, density):
        a = sp.random(n, n, density=density, random_state=rng) + sp.eye(n)
        dense = (a @ a.T).toarray() + np.eye(n)
        lower = sp.csc_matrix(np.tril(dense))
        lower.sort_indices()
        return dense, lower

    rhs = rng.standard_normal(12)
    dense, lower = system(12, 0.2)
    np.testing.assert_allclose(solver.solve(lower, rhs), np.linalg.solve(dense, rhs), rtol=1e-10)
    symbolic = solver._symbolic
    scaled = lower.copy()
    scaled.data = 2.0 * lower.data  # same pattern, new values: numeric refactorisation only
    np.testing.assert_allclose(solver.solve(scaled, rhs), np.linalg.solve(2.0 * dense, rhs), rtol=1e-10)
    assert solver._symbolic is symbolic
    dense2, lower2 = system(12, 0.5)  # another pattern: analysed again
    np.testing.assert_allclose(solver.solve(lower2, rhs), np.linalg.solve(dense2, rhs), rtol=1e-10)
    assert solver._symbolic is not symbolic
    indefinite = lower2.copy()
    indefinite.data[_diagonal_positions(indefinite)] -= 2.0 * np.abs(dense2).sum()
    with pytest.raises(ValueError, match="not positive definite"):
        solver.solve(indefinite, rhs)
    np.testing.assert_allclose(solver.solve(lower2, rhs), np.linalg.solve(dense2, rhs), rtol=1e-10)  # still usable


def test_project_psd_keeps_psd_matrices():
    gen = torch.Generator().manual_seed(3)
    a = torch.randn(5, 6, 6, generator=gen, dtype=torch.float64)
    spd = a @ a.transpose(-1, -2)
    torch.testing.assert_close(project_psd(spd), spd)
    assert torch.linalg.eigvalsh(project_psd(a + a.transpose(-1, -2))).min() > -1e-12


def test_relax_penalty_top_on_body(body):
    garment = _top()
    cloth = Cloth.build(garment)
    inside_seen = []
    result = relax(garment.rest.clone(), cloth, body, max_iters=150,
                   callback=lambda rec, x: inside_seen.append(bool(body.query(x).inside.any())))
    assert isinstance(result, OracleResult)
    assert result.converged and result.reason == "converged", result.reason
    energies = [rec.energy for rec in result.history]
    assert all(b <= a for a, b in zip(energies, energies[1:]))  # monotone decrease
    assert energies[-1] < energies[0] - 1e-4  # and a real one
    assert not any(inside_seen) and all(rec.num_inside == 0 for rec in result.history)
    assert result.history[-1].residual < 1e-2
    assert result.history[-1].num_contact > 0  # held up by the body
    terms = result.energy_terms
    torch.testing.assert_close(terms["total"], terms["strain"] + terms["bend"] + terms["gravity"] + terms["contact"])
    # the contact it minimises is `physics.contact`'s term (vertices and face centroids)
    contact = penalty_contact_energy(result.x, cloth, body, torch.zeros(cloth.num_verts, dtype=torch.int64))
    assert float(contact) > 0
    torch.testing.assert_close(terms["contact"], contact, rtol=1e-12, atol=0.0)
    assert result.x.dtype == garment.rest.dtype and torch.isfinite(result.x).all()


def test_relax_keeps_face_centroids_out_of_the_body(body):
    """A coarse top (12 segments) rests on the cone with its faces' middles on the body: the chords
    between vertices would cut ~3 mm into it, so vertex contact alone would let faces in."""
    garment = _top(rings=6, segments=12, lift=0.008)
    centroids_inside = []
    result = relax(garment.rest.clone(), Cloth.build(garment), body, max_iters=150,
                   callback=lambda rec, x: centroids_inside.append(int(body.query(x[garment.faces].mean(1)).inside.sum())))
    assert result.converged
    assert max(centroids_inside) == 0
    centroid_distance = body.query(result.x[garment.faces].mean(1)).signed_distance
    assert float(centroid_distance.min()) < 1e-3  # faces do bear on the body (the case is not vacuous)
    assert float(body.query(result.x).signed_distance.min()) > 2e-3  # while every vertex is clear of it


@pytest.mark.parametrize("bend, projection", [("projected", "always"), ("gauss_newton", "always")])
def test_relax_other_hessian_modes_reach_the_same_drape(body, bend, projection):
    garment = _top()
    cloth = Cloth.build(garment)
    ref = relax(garment.rest.clone(), cloth, body, max_iters=150)
    other = relax(garment.rest.clone(), cloth, body, max_iters=300, bend=bend, projection=projection)
    assert other.converged and all(rec.projected for rec in other.history[1:])
    energies = [rec.energy for rec in other.history]
    assert all(b <= a for a, b in zip(energies, energies[1:]))
    torch.testing.assert_close(other.energy_terms["total"], ref.energy_terms["total"], rtol=1e-4, atol=0)


def test_relax_batch_equals_singles(body):
    """A packed batch solves each garment on its own (block-diagonal system, own step lengths)."""
    tubes = [_top(), _top(rings=5, segments=16, lift=0.008, hem=0.15)]
    batch = GarmentBatch.pack(tubes)
    kwargs = dict(max_iters=150, tol=1e-2)
    packed = relax(batch.rest.clone(), Cloth.build(batch), body, **kwargs)
    assert packed.converged
    for g, tube in enumerate(tubes):
        single = relax(tube.rest.clone(), Cloth.build(tube), body, **kwargs)
        torch.testing.assert_close(packed.energy_terms["total"][g], single.energy_terms["total"][0],
                                   rtol=1e-5, atol=1e-9)


def test_relax_budget_and_input_checks(body):
    garment = _top()
    cloth = Cloth.build(garment)
    result = relax(garment.rest.clone(), cloth, body, max_iters=2)
    assert result.reason == "max_iters" and not result.converged and len(result.history) == 3
    with pytest.raises(ValueError, match="packed positions"):
        relax(garment.rest[:-1], cloth, body)
    with pytest.raises(ValueError, match="body_index"):
        relax(garment.rest, cloth, body, body_index=torch.tensor([1]))


def test_relax_superlu_matches_default(body):
    garment = _top(rings=5, segments=12)
    cloth = Cloth.build(garment)
    a = relax(garment.rest.clone(), cloth, body, max_iters=40, solver="superlu")
    b = relax(garment.rest.clone(), cloth, body, max_iters=40)
    assert a.converged and b.converged
    torch.testing.assert_close(a.energy_terms["total"], b.energy_terms["total"], rtol=1e-5, atol=0)


@pytest.mark.skipif(not HAS_IPCTK, reason="ipctk not installed (pip install ipctk)")
def test_relax_ipc_top_on_body(body):
    import ipctk

    garment = _top(rings=5, segments=24, lift=0.01)
    cloth = Cloth.build(garment)
    result = relax(garment.rest.clone(), cloth, body, contact="ipc", max_iters=25)
    assert result.converged, result.reason
    energies = [rec.energy for rec in result.history]
    assert all(b <= a for a, b in zip(energies, energies[1:]))
    assert energies[-1] < energies[0]
    assert all(rec.num_inside == 0 for rec in result.history)
    # intersection-free by construction (CCD-clipped steps)
    x = result.x.numpy()
    body_v = body.verts[0].numpy()
    faces = np.concatenate([cloth.faces.numpy(), body.faces.numpy() + len(x)]).astype(np.int32)
    mesh = ipctk.CollisionMesh(np.asfortranarray(np.concatenate([x, body_v])),
                               np.asfortranarray(ipctk.edges(faces)), np.asfortranarray(faces))
    assert not ipctk.has_intersections(mesh, np.asfortranarray(np.concatenate([x, body_v])))


def test_ipc_missing_gives_install_hint(body, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "ipctk":
            raise ImportError("no ipctk")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    garment = _top(rings=3, segments=8)
    with pytest.raises(ImportError, match="pip install ipctk"):
        relax(garment.rest.clone(), Cloth.build(garment), body, contact="ipc")


def test_public_names():
    import physdrape.physics
    from physdrape.physics.oracle import (
        BendHessian,
        ContactMode,
        IterationRecord,
        LinearSolver,
        Projection,
        silenced,
    )

    assert physdrape.physics.relax is relax
    assert {ContactMode("ipc"), Projection("always"), BendHessian("projected"), LinearSolver("superlu")}
    assert IterationRecord(0, 0.0, 0.0, 0.0, 0.0, 0.0, 0, 0).projected
    with silenced(1):
        print("not shown")


def _collar_over_top(*, height=0.40):
    """Two pieces in one garment: the small top (resting on the cone's shoulders) and a flat ring
    above its shoulders that gravity pulls down through the top onto the body."""
    top = _top()
    rings, segments = 3, 24
    verts, faces = open_cylinder(rings, segments, radius=1.0, length=1.0)
    radius = np.linspace(0.09, 0.15, rings)[np.repeat(np.arange(rings), segments)]
    verts[:, [0, 2]] *= radius[:, None]
    verts[:, 1] = height
    top_verts = top.rest.numpy()
    return Garment.from_mesh(np.concatenate([top_verts, verts]),
                             np.concatenate([top.faces.numpy(), faces + len(top_verts)]))


def test_relax_does_not_carry_one_piece_through_another(body, monkeypatch):
    """The energy has no term between two pieces without layer pairs: left alone, the oracle lets
    the ring fall through the top onto the body; its line search refuses the steps that make the
    two pieces' faces intersect (`physics.oracle.crossings.PieceGuard`), and the step searched
    instead holds the corners of those faces, so that the rest of the ring settles on: without
    that hold the oracle stops where the ring first touches the top."""
    from physdrape.geometry.intersections import piece_crossings
    from physdrape.physics.oracle import crossings, newton

    garment = _collar_over_top()
    cloth = Cloth.build(garment)
    faces = garment.faces.numpy()
    assert piece_crossings(garment.rest.numpy(), faces) == 0
    guarded = relax(garment.rest.clone(), cloth, body, max_iters=60)
    assert piece_crossings(guarded.x.numpy(), faces) == 0
    ring = slice(len(_top().rest), None)
    assert float(guarded.x[ring, 1].mean()) < 0.40 - 0.02  # it did fall, onto the top
    assert guarded.reason == "max_iters"  # it goes on settling
    with monkeypatch.context() as patch:
        patch.setattr(newton, "HOLD_ROUNDS", 0)
        stuck = relax(garment.rest.clone(), cloth, body, max_iters=60)
    assert stuck.reason == "line_search" and len(stuck.history) < len(guarded.history)
    assert float(guarded.energy_terms["total"]) < float(stuck.energy_terms["total"])
    monkeypatch.setattr(crossings.PieceGuard, "of", staticmethod(lambda *args: None))
    unguarded = relax(garment.rest.clone(), cloth, body, max_iters=60)
    assert piece_crossings(unguarded.x.numpy(), faces) > 0
    assert float(unguarded.energy_terms["total"]) < float(guarded.energy_terms["total"])


def test_piece_guard_flags_only_new_crossings_between_pieces_of_one_garment():
    """Two triangles of two pieces: crossing only when moved through each other; a pair already
    crossed is not new; two garments' faces that intersect are no crossing of pieces."""
    from physdrape.physics.oracle.crossings import PieceGuard

    faces = torch.tensor([[0, 1, 2], [3, 4, 5]])
    apart = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0.2, 0.1, 0.2], [0.2, 0.1, 0.6], [0.6, 0.1, 0.2]],
                         dtype=torch.float64)
    through = apart.clone()
    through[4:, 1] = -0.1  # one corner above the first triangle's plane, two below: it pierces it
    one = PieceGuard.of(faces, torch.tensor([0, 0]), 6, 1)
    assert one is not None and one.pairs(apart).size == 0 and one.pairs(through).size == 1
    fresh = one.new_pairs(through, one.pairs(apart))
    assert fresh.tolist() == [[0, 1]] and one.garments(fresh).tolist() == [True]
    assert one.vertices(fresh, 6).all()
    assert one.new_pairs(through, one.pairs(through)).size == 0
    assert one.known(apart) is one.known(apart) and one.known(through).size == 1  # kept per tensor
    assert PieceGuard.of(faces, torch.tensor([0, 1]), 6, 2) is None  # each garment in one piece
