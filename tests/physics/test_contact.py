"""The body-contact penalty (`physics.contact`), float64: forces are −∇ of the energy (autograd and
central differences, on held planes and through the live body query), Gauss–Newton blocks are the
Hessian on held planes, and the per-garment sums."""

from functools import partial

import numpy as np
import pytest
import torch
import trimesh

from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import open_cylinder
from physdrape.geometry.proximity import BodySurface, SignMethod
from physdrape.physics import Cloth
from physdrape.physics.contact import (
    PlaneFollower,
    contact_energy,
    contact_hessian_blocks,
    contact_samples,
    contact_vertices,
    follow_planes,
    garment_energy,
    penalty_contact_energy,
    plane_contact_blocks,
    plane_contact_forces,
    plane_distance,
    query_samples,
    sample_index,
    samples_at,
    to_vertices,
)

K_C, EPS = 2.5e3, 2e-3


@pytest.fixture(scope="module")
def body() -> BodySurface:
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.15)
    return BodySurface(torch.tensor(np.asarray(sphere.vertices)), torch.tensor(np.asarray(sphere.faces)))


def _band(radius=0.152, seed=0, rings=3, segments=20) -> tuple[Garment, torch.Tensor]:
    """A short tube around the sphere's equator, its samples scattered about the margin, float64."""
    verts, faces = open_cylinder(rings, segments, radius=radius, length=0.04)
    verts[:, 1] -= 0.02
    garment = Garment.from_mesh(verts, faces)
    gen = torch.Generator().manual_seed(seed)
    return garment, garment.rest + 1e-3 * torch.randn(garment.rest.shape, generator=gen, dtype=torch.float64)


def _planes(body, x, faces):
    q = query_samples(x, faces, body, None)
    return q.closest, q.normal, q.signed_distance


def test_samples_at_are_those_rows_of_the_samples():
    garment, x = _band()
    faces = garment.faces
    num_samples = x.shape[0] + faces.shape[0]
    rows = torch.tensor([0, num_samples - 1, x.shape[0], x.shape[0] - 1, 5, x.shape[0] + 7, 5])
    assert torch.equal(samples_at(x, faces, rows), contact_samples(x, faces)[rows])
    assert samples_at(x, faces, rows[:0]).shape == (0, 3)


def _plane_energy(x, faces, closest, normal):
    distance = ((contact_samples(x, faces) - closest) * normal).sum(-1)
    return contact_energy(distance, stiffness=K_C, margin=EPS).sum()


def test_the_case_has_vertices_and_centroids_in_and_out_of_contact(body):
    garment, x = _band()
    _, _, distance = _planes(body, x, garment.faces)
    dv, dc = distance[:garment.num_verts], distance[garment.num_verts:]
    for d in (dv, dc):
        assert (d < EPS).sum() > 5 and (d > EPS).sum() > 5


def test_force_is_negative_autograd_gradient_on_held_planes(body):
    garment, x = _band()
    closest, normal, distance = _planes(body, x, garment.faces)
    xg = x.clone().requires_grad_()
    (grad,) = torch.autograd.grad(_plane_energy(xg, garment.faces, closest, normal), xg)
    assert grad.abs().max() > 1e-6, "test point is stationary: the comparison would prove nothing"
    f = plane_contact_forces(x, garment.faces, closest, normal, stiffness=K_C, margin=EPS)
    torch.testing.assert_close(f, -grad, rtol=1e-10, atol=1e-14)
    # the kernel's distances are the planes' (s − p)·n, which the query gave at x
    torch.testing.assert_close(plane_distance(x, garment.faces, closest, normal), distance, rtol=0, atol=1e-15)


def test_force_backward_is_the_hessian_vector_product_on_held_planes(body):
    garment, x = _band(seed=2)
    closest, normal, _ = _planes(body, x, garment.faces)
    direction = torch.randn(x.shape, generator=torch.Generator().manual_seed(5), dtype=x.dtype)
    xg = x.clone().requires_grad_()
    f = plane_contact_forces(xg, garment.faces, closest, normal, stiffness=K_C, margin=EPS)
    (hv,) = torch.autograd.grad(f, xg, grad_outputs=direction)
    exact = torch.autograd.functional.hvp(lambda xt: _plane_energy(xt, garment.faces, closest, normal), x, direction)[1]
    assert exact.abs().max() > 1e-3
    torch.testing.assert_close(hv, -exact, rtol=1e-10, atol=1e-12 * float(exact.abs().max()))


def test_float32_positions_get_the_float64_contact_in_float32():
    garment, x = _band(seed=6)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.15)
    body32 = BodySurface(torch.tensor(np.asarray(sphere.vertices), dtype=torch.float32),
                         torch.tensor(np.asarray(sphere.faces)))
    closest, normal, _ = _planes(body32, x.float(), garment.faces)
    x32 = x.float()
    f64 = plane_contact_forces(x32.double(), garment.faces, closest.double(), normal.double(), stiffness=K_C,
                               margin=EPS)
    f32 = plane_contact_forces(x32, garment.faces, closest, normal, stiffness=K_C, margin=EPS)
    assert f32.dtype == torch.float32 and f64.abs().max() > 1e-3
    assert torch.equal(f32, f64.float())  # float64 arithmetic, rounded once


def test_plane_functions_check_the_planes_shape(body):
    garment, x = _band()
    closest, normal, _ = _planes(body, x, garment.faces)
    with pytest.raises(ValueError, match="the V \\+ F samples"):
        plane_distance(x, garment.faces, closest[:-1], normal)


def test_force_matches_central_differences_of_the_queried_energy(body):
    """Through the live body query (closest point re-found at every trial state)."""
    garment, x = _band(seed=1)
    cloth = Cloth.build(garment)
    vert_body = torch.zeros(garment.num_verts, dtype=torch.int64)
    q = query_samples(x, garment.faces, body, vert_body)
    f = plane_contact_forces(x, garment.faces, q.closest, q.normal, stiffness=K_C, margin=EPS)

    def energy(xt):
        return float(penalty_contact_energy(xt, cloth, body, vert_body, stiffness=K_C, margin=EPS).sum())

    gen = torch.Generator().manual_seed(3)
    h = 1e-7
    for _ in range(5):
        direction = torch.randn(x.shape, generator=gen, dtype=x.dtype)
        direction /= direction.norm()
        fd = (energy(x + h * direction) - energy(x - h * direction)) / (2 * h)
        analytic = -float((f * direction).sum())
        assert abs(fd) > 1e-6, "finite-difference signal is zero: not a meaningful test point"
        assert analytic == pytest.approx(fd, rel=1e-5)


def test_the_penalty_energy_and_its_gradient_are_those_of_the_query_of_every_sample(body):
    """The centroids it does not search (far from the body by their corners) add exactly 0."""
    garment, x = _band(seed=1)
    cloth = Cloth.build(garment)
    vert_body = torch.zeros(garment.num_verts, dtype=torch.int64)
    # the band as it is (in contact all round), moved 3 cm sideways (one side in the body, the far
    # side's centroids not searched) and widened to a 5 cm gap (none searched, no energy)
    for scale, shift in ((1.0, 0.0), (1.0, 0.03), (0.2 / 0.152, 0.0)):
        xt = (x * torch.tensor([scale, 1.0, scale], dtype=x.dtype) + torch.tensor([shift, 0.0, 0.0], dtype=x.dtype))
        xt.requires_grad_(True)
        energy = penalty_contact_energy(xt, cloth, body, vert_body, stiffness=K_C, margin=EPS)
        distance = query_samples(xt, garment.faces, body, vert_body).signed_distance
        every = garment_energy(contact_energy(distance, stiffness=K_C, margin=EPS), cloth)
        assert torch.equal(energy, every)
        assert torch.equal(torch.autograd.grad(energy.sum(), xt)[0], torch.autograd.grad(every.sum(), xt)[0])
    assert float(every.sum()) == 0.0 and float(penalty_contact_energy(x, cloth, body, vert_body, stiffness=K_C,
                                                                       margin=EPS).sum()) > 0.0


def test_gauss_newton_blocks_are_the_hessian_on_held_planes(body):
    garment, x = _band(seed=3)
    faces, num_verts = garment.faces, garment.num_verts
    closest, normal, distance = _planes(body, x, faces)
    vertex, face = contact_hessian_blocks(distance, normal, faces, stiffness=K_C, margin=EPS)
    assert vertex.shape == (num_verts, 3, 3) and face.shape == (faces.shape[0], 9, 9)
    assembled = torch.zeros(num_verts, 3, num_verts, 3, dtype=x.dtype)
    idx = torch.arange(num_verts)
    assembled[idx, :, idx, :] += vertex
    for f, corners in enumerate(faces.tolist()):
        for a, i in enumerate(corners):
            for b, j in enumerate(corners):
                assembled[i, :, j, :] += face[f, 3 * a:3 * a + 3, 3 * b:3 * b + 3]
    assembled = assembled.reshape(3 * num_verts, 3 * num_verts)
    exact = torch.autograd.functional.hessian(lambda xt: _plane_energy(xt, faces, closest, normal), x)
    exact = exact.reshape(3 * num_verts, 3 * num_verts)
    assert exact.abs().max() > 1e-3
    torch.testing.assert_close(assembled, exact, rtol=1e-10, atol=1e-10 * float(exact.abs().max()))
    # the per-vertex blocks are the diagonal blocks of that Hessian
    diagonal = exact.reshape(num_verts, 3, num_verts, 3)[idx, :, idx, :]
    torch.testing.assert_close(plane_contact_blocks(x, faces, closest, normal, stiffness=K_C, margin=EPS), diagonal,
                               rtol=1e-10, atol=1e-10 * float(exact.abs().max()))


def test_blocks_within_the_band_are_taken_at_depth_at_least_the_margin(body):
    garment, x = _band(seed=3)
    faces, num_verts = garment.faces, garment.num_verts
    closest, normal, distance = _planes(body, x, faces)
    band = 0.01
    assert ((distance > EPS) & (distance < band)).sum() > 5, "no sample between margin and band: proves nothing"
    # the same blocks as the exact ones at the distances the band substitutes
    depth_distance = torch.where(distance < band, distance.clamp_max(0.0), distance)
    vertex, face = contact_hessian_blocks(depth_distance, normal, faces, stiffness=K_C, margin=EPS)
    expected = vertex.index_add(0, faces.reshape(-1), face.reshape(-1, 3, 3, 3, 3).diagonal(dim1=1, dim2=3)
                                .permute(0, 3, 1, 2).reshape(-1, 3, 3))
    got = plane_contact_blocks(x, faces, closest, normal, stiffness=K_C, margin=EPS, band=band)
    torch.testing.assert_close(got, expected, rtol=1e-10, atol=1e-12 * float(expected.abs().max()))
    assert got.shape == (num_verts, 3, 3)


def test_second_derivative_along_the_normal_matches_finite_differences(body):
    """One vertex moved along its own plane's normal: d²E/dh² = 6 k_c ReLU(ε − d) (plus its faces'
    centroid shares), by central differences of the energy on held planes."""
    garment, x = _band(seed=4)
    faces = garment.faces
    closest, normal, distance = _planes(body, x, faces)
    vertex, _ = contact_hessian_blocks(distance, normal, faces, stiffness=K_C, margin=EPS)
    depth = (EPS - distance[:garment.num_verts]).clamp_min(0)
    i = int(torch.argmax(depth))
    assert depth[i] > 1e-4
    n = torch.zeros_like(x)
    n[i] = normal[i]
    h = 1e-6

    def e(t):
        return float(_plane_energy(x + t * n, faces, closest, normal))

    fd = (e(h) - 2 * e(0.0) + e(-h)) / h**2
    block = plane_contact_blocks(x, faces, closest, normal, stiffness=K_C, margin=EPS)[i]
    assert float(normal[i] @ block @ normal[i]) == pytest.approx(fd, rel=1e-4)
    own = float(normal[i] @ vertex[i] @ normal[i])
    assert own == pytest.approx(6 * K_C * float(depth[i]), rel=1e-12)


def test_energy_per_garment_and_the_centroid_share():
    batch = GarmentBatch.pack([_band()[0], _band(radius=0.16)[0]])
    cloth = Cloth.build(batch)
    gen = torch.Generator().manual_seed(5)
    per_sample = torch.rand(cloth.num_verts + cloth.faces.shape[0], generator=gen, dtype=torch.float64)
    owner = sample_index(cloth.vert_garment, cloth.faces)
    expected = torch.zeros(2, dtype=torch.float64).index_add_(0, owner, per_sample)
    torch.testing.assert_close(garment_energy(per_sample, cloth), expected)
    # to_vertices keeps the total, each centroid split 1/3 per corner
    torch.testing.assert_close(to_vertices(per_sample, cloth.faces).sum(), per_sample.sum())
    distance = torch.full_like(per_sample, 1.0)
    distance[cloth.num_verts] = 0.0  # the first face's centroid only
    flags = contact_vertices(distance, cloth.faces, margin=EPS)
    assert flags.nonzero().flatten().tolist() == sorted(cloth.faces[0].tolist())
    assert (contact_energy(torch.tensor([EPS, 1.0]), stiffness=K_C, margin=EPS) == 0).all()


def _overlapping_spheres() -> BodySurface:
    """A body of two overlapping spheres (a limb pressed into the torso): the pseudo-normal sign
    is wrong inside the overlap, where a query takes the winding number."""
    big, small = trimesh.creation.icosphere(3, radius=0.15), trimesh.creation.icosphere(3, radius=0.10)
    verts = np.concatenate([big.vertices, small.vertices + [0.2, 0.0, 0.0]])
    faces = np.concatenate([big.faces, small.faces + len(big.vertices)])
    return BodySurface(torch.tensor(verts), torch.tensor(faces))


@pytest.mark.parametrize("min_move", [0.0, 1.5e-3])
def test_followed_planes_are_the_planes_a_query_walking_from_the_held_faces_finds(min_move, winding_searches):
    """`follow_planes` gives the samples within the band of their held planes (and moved farther
    than min_move since found_at) the closest point, normal and face of `BodySurface.query` walking
    from their held faces, the winding number's sign included where it is in doubt; the others
    keep their planes; the change is each sample's penalty on the new plane minus the old one."""
    body = _overlapping_spheres()
    verts, faces = body.verts[0], body.faces  # a cloth hugging the body over the overlap, off it at the far side
    normals = torch.tensor(trimesh.Trimesh(verts.numpy(), faces.numpy(), process=False).vertex_normals)
    gen = torch.Generator().manual_seed(5)
    offset = torch.where(verts[:, 0] < -0.05, 1e-2, 1e-3)[:, None]
    x0 = verts + offset * normals + 1e-3 * torch.randn(verts.shape, generator=gen, dtype=torch.float64)
    held = query_samples(x0, faces, body, None)
    x = x0 + 2e-3 * torch.randn(x0.shape, generator=gen, dtype=torch.float64)
    band = 4e-3
    out = follow_planes(x, faces, held.closest, held.normal, held.face, contact_samples(x0, faces), body, None,
                        band=band, min_move=min_move, stiffness=K_C, margin=EPS)
    samples = contact_samples(x, faces)
    before = ((samples - held.closest) * held.normal).sum(-1)
    follow = before < band
    if min_move:
        follow &= (samples - contact_samples(x0, faces)).norm(dim=-1) > min_move
    rows = torch.nonzero(follow)[:, 0]
    assert 500 < rows.numel() < samples.shape[0] - 500  # both kinds of samples occur
    want = body.query(samples[rows], near=held.face[rows])
    assert torch.equal(out.face[rows], want.face)
    torch.testing.assert_close(out.closest[rows], want.closest, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.normal[rows], want.normal, rtol=0, atol=1e-12)
    torch.testing.assert_close(out.found_at[rows], samples[rows], rtol=0, atol=1e-15)
    kept = torch.nonzero(~follow)[:, 0]
    assert torch.equal(out.closest[kept], held.closest[kept]) and torch.equal(out.normal[kept], held.normal[kept])
    assert torch.equal(out.face[kept], held.face[kept]) and not out.change[kept].any()
    after = ((samples[rows] - want.closest) * want.normal).sum(-1)
    penalty = partial(contact_energy, stiffness=K_C, margin=EPS)
    torch.testing.assert_close(out.change[rows], penalty(after) - penalty(before[rows]), rtol=1e-12, atol=1e-18)
    # the winding number mattered: without it some followed samples in the overlap get the other sign
    pseudo = BodySurface(body.verts, faces, sign_method=SignMethod.PSEUDO_NORMAL)
    wrong = pseudo.query(samples[rows], near=held.face[rows])
    assert ((wrong.normal * want.normal).sum(-1) < 0).sum() > 10
    # on bodies that have not found their doubtful faces yet, every followed sample is in doubt
    # (as a query takes it then): the same planes
    fresh = _overlapping_spheres()
    assert fresh.found_doubtful_faces() is None and body.found_doubtful_faces() is not None
    again = follow_planes(x, faces, held.closest, held.normal, held.face, contact_samples(x0, faces), fresh, None,
                          band=band, min_move=min_move, stiffness=K_C, margin=EPS)
    for field in ("closest", "normal", "face", "found_at", "change"):
        assert torch.equal(getattr(again, field), getattr(out, field)), field
    # with the held query's bound, the samples in doubt that cannot have crossed the surface keep
    # their side without a winding number: the same planes from fewer winding numbers
    winding_searches.clear()
    asked = winding_searches
    follower = PlaneFollower(faces, x.shape[0], body, None, band=band, min_move=min_move, stiffness=K_C, margin=EPS,
                             device=x.device)
    for bound in (None, DistanceBound.of(contact_samples(x0, faces), held.signed_distance)):
        follower.hold(held.closest, held.normal, held.face, contact_samples(x0, faces))
        change = follower(x, bound=bound)  # the planes moved in place
        torch.testing.assert_close(change, out.change, rtol=0, atol=0)
        for field in ("closest", "normal", "face", "found_at"):
            assert torch.equal(getattr(follower, field).to(getattr(out, field).dtype), getattr(out, field)), field
    assert len(asked) == 2 and asked[1] < asked[0]
