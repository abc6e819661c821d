"""Body-surface queries (physdrape.geometry.proximity) against slow pure-torch twins.

Synthetic bodies only (icosphere, torus, bumpy non-convex blob, an open sphere); the Anny check
at the end runs only where the ``anny_body`` fixture exists.
"""

from __future__ import annotations

import math

import pytest
import torch
import trimesh

from physdrape.geometry.closest_point import closest_point_on_triangle
from surface_normals_reference import angle_weighted_vertex_normals
from physdrape.geometry.proximity import (
    BodySurface,
    SignMethod,
    SurfaceQuery,
    query_body_surface,
)

EPS = 2e-3  # collision margin of the handler [m]


# ---------------------------------------------------------------------------------------------
# Synthetic bodies (metres, body-like sizes)
# ---------------------------------------------------------------------------------------------


def icosphere(subdivisions: int = 3, radius: float = 0.15) -> tuple[torch.Tensor, torch.Tensor]:
    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return torch.tensor(m.vertices, dtype=torch.float64), torch.tensor(m.faces, dtype=torch.int64)


def torus(major: float = 0.2, minor: float = 0.07, nu: int = 40, nv: int = 20) -> tuple[torch.Tensor, torch.Tensor]:
    """Closed torus around the y axis, outward-wound."""
    u = torch.arange(nu, dtype=torch.float64) * 2 * math.pi / nu
    v = torch.arange(nv, dtype=torch.float64) * 2 * math.pi / nv
    uu, vv = torch.meshgrid(u, v, indexing="ij")
    verts = torch.stack([(major + minor * torch.cos(vv)) * torch.cos(uu), minor * torch.sin(vv),
                         (major + minor * torch.cos(vv)) * torch.sin(uu)], -1).reshape(-1, 3)
    i, j = torch.meshgrid(torch.arange(nu), torch.arange(nv), indexing="ij")
    a = i * nv + j
    b = ((i + 1) % nu) * nv + j
    c = ((i + 1) % nu) * nv + (j + 1) % nv
    d = i * nv + (j + 1) % nv
    faces = torch.cat([torch.stack([a, d, c], -1).reshape(-1, 3), torch.stack([a, c, b], -1).reshape(-1, 3)])
    # Orient outward (checked by the signed volume).
    tri = verts[faces]
    vol = (tri[:, 0] * torch.cross(tri[:, 1], tri[:, 2], dim=-1)).sum()
    if vol < 0:
        faces = faces[:, [0, 2, 1]]
    return verts, faces


def bumpy_blob() -> tuple[torch.Tensor, torch.Tensor]:
    """Non-convex star-shaped blob with concave valleys (radius 0.12-0.18 m)."""
    verts, faces = icosphere(3, 1.0)
    dirs = verts / verts.norm(dim=-1, keepdim=True)
    r = 0.15 + 0.03 * torch.sin(3 * torch.atan2(dirs[:, 2], dirs[:, 0])) * torch.cos(2 * dirs[:, 1])
    return dirs * r[:, None], faces


MESHES = {"icosphere": icosphere, "torus": torus, "bumpy": bumpy_blob}


# ---------------------------------------------------------------------------------------------
# Slow twins: brute force over all faces, written independently of the module
# ---------------------------------------------------------------------------------------------


def _segment_dist2(x, a, b):
    ab = b - a
    t = (((x - a) * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-300)).clamp(0, 1)
    q = a + t[..., None] * ab
    return ((x - q) ** 2).sum(-1), q


def brute_force_closest(x: torch.Tensor, verts: torch.Tensor, faces: torch.Tensor):
    """Exact closest point over all triangles: plane projection if inside, else the 3 edges.

    Returns distance (N,), closest point (N, 3), face (N,), gap to the second-best face (N,).
    """
    tri = verts[faces]  # (F, 3, 3)
    a, b, c = (tri[None, :, k] for k in range(3))
    xx = x[:, None]
    n = torch.cross(b - a, c - a, dim=-1)
    n = n / n.norm(dim=-1, keepdim=True)
    proj = xx - ((xx - a) * n).sum(-1, keepdim=True) * n
    # Inside test by the signs of the sub-triangle normals.
    s0 = (torch.cross(b - a, proj - a, dim=-1) * n).sum(-1)
    s1 = (torch.cross(c - b, proj - b, dim=-1) * n).sum(-1)
    s2 = (torch.cross(a - c, proj - c, dim=-1) * n).sum(-1)
    inside = (s0 >= 0) & (s1 >= 0) & (s2 >= 0)
    edge2, edgeq = None, None
    for p0, p1 in ((a, b), (b, c), (c, a)):
        d2, q = _segment_dist2(xx, p0, p1)
        if edge2 is None:
            edge2, edgeq = d2, q
        else:
            take = d2 < edge2
            edge2 = torch.where(take, d2, edge2)
            edgeq = torch.where(take[..., None], q, edgeq)
    best2 = torch.where(inside, ((xx - proj) ** 2).sum(-1), edge2)
    bestq = torch.where(inside[..., None], proj, edgeq)
    dist = best2.sqrt()
    top2 = torch.topk(dist, min(2, len(faces)), dim=1, largest=False)
    face = top2.indices[:, 0]
    closest = bestq[torch.arange(len(x)), face]
    gap = top2.values[:, -1] - top2.values[:, 0] if len(faces) > 1 else torch.full_like(dist[:, 0], math.inf)
    return top2.values[:, 0], closest, face, gap


def brute_force_winding_number(x: torch.Tensor, verts: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Generalized winding number (Van Oosterom-Strackee solid angles / 4 pi), shape (N,)."""
    tri = verts[faces][None] - x[:, None, None]  # (N, F, 3, 3)
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    la, lb, lc = a.norm(dim=-1), b.norm(dim=-1), c.norm(dim=-1)
    num = (a * torch.cross(b, c, dim=-1)).sum(-1)
    den = la * lb * lc + (a * b).sum(-1) * lc + (b * c).sum(-1) * la + (c * a).sum(-1) * lb
    return (2 * torch.atan2(num, den)).sum(-1) / (4 * math.pi)


def overlapping_spheres():
    """Two spheres in one mesh, radii 15 and 10 cm, centres 20 cm apart (a limb pressed into the
    torso): verts (V, 3) float64, faces (F, 3)."""
    a_verts, a_faces = icosphere(3, 0.15)
    b_verts, b_faces = icosphere(3, 0.10)
    verts = torch.cat([a_verts, b_verts + torch.tensor([0.2, 0.0, 0.0], dtype=torch.float64)])
    return verts, torch.cat([a_faces, b_faces + len(a_verts)])


def sample_points(verts, faces, n_near: int, n_far: int, seed: int, offset: float = 0.03):
    """Points near the surface (random face point + normal offset) and far (in a loose box)."""
    g = torch.Generator().manual_seed(seed)
    tri = verts[faces]
    f = torch.randint(0, len(faces), (n_near,), generator=g)
    w = -torch.log(torch.rand(n_near, 3, generator=g, dtype=torch.float64))
    w = w / w.sum(-1, keepdim=True)
    on = (tri[f] * w[..., None]).sum(1)
    nrm = torch.cross(tri[f, 1] - tri[f, 0], tri[f, 2] - tri[f, 0], dim=-1)
    nrm = nrm / nrm.norm(dim=-1, keepdim=True)
    near = on + nrm * (torch.rand(n_near, 1, generator=g, dtype=torch.float64) * 2 - 1) * offset
    lo, hi = verts.min(0).values, verts.max(0).values
    centre, half = (lo + hi) / 2, (hi - lo) / 2
    far = centre + (torch.rand(n_far, 3, generator=g, dtype=torch.float64) * 2 - 1) * half * 2.0
    return torch.cat([near, far])


# ---------------------------------------------------------------------------------------------
# Tests
# ---------------------------------------------------------------------------------------------


def test_closest_point_on_triangle_matches_brute_force():
    g = torch.Generator().manual_seed(0)
    tri = torch.rand(500, 3, 3, generator=g, dtype=torch.float64)
    x = torch.rand(500, 3, generator=g, dtype=torch.float64) * 3 - 1
    p, bary = closest_point_on_triangle(x, tri[:, 0], tri[:, 1], tri[:, 2])
    for i in range(0, 500, 7):
        dist, q, _, _ = brute_force_closest(x[i:i + 1], tri[i], torch.tensor([[0, 1, 2]]))
        assert torch.allclose(p[i], q[0], atol=1e-12)
    assert torch.allclose(bary.sum(-1), torch.ones(500, dtype=torch.float64))
    assert (bary >= -1e-12).all()
    assert torch.allclose((bary[..., None] * tri).sum(1), p, atol=1e-12)


@pytest.mark.parametrize("name", list(MESHES))
@pytest.mark.parametrize("sign_method", list(SignMethod))
def test_query_matches_brute_force(name, sign_method):
    verts, faces = MESHES[name]()
    x = sample_points(verts, faces, 600, 200, seed=1)
    q = BodySurface(verts, faces, sign_method=sign_method).query(x)
    dist, closest, face, gap = brute_force_closest(x, verts, faces)
    wn = brute_force_winding_number(x, verts, faces)

    assert q.closest.shape == (len(x), 3) and q.signed_distance.shape == (len(x),)
    assert q.face.dtype == torch.int64 and q.inside.dtype == torch.bool
    assert q.closest.dtype == torch.float64
    # Distances: the BVH searches in float32, the chosen face is exact to ~1e-7 m.
    assert torch.allclose(q.signed_distance.abs(), dist, atol=1e-6, rtol=0)
    assert torch.allclose((x - q.closest).norm(dim=-1), dist, atol=1e-6, rtol=0)
    # Closest point and face, where the closest face is unambiguous.
    clear = gap > 1e-4
    assert clear.sum() > 0.3 * len(x)
    assert torch.allclose(q.closest[clear], closest[clear], atol=1e-6)
    # Barycentrics reproduce the closest point on the reported face.
    corners = verts[faces[q.face]]
    assert torch.allclose((q.bary[..., None] * corners).sum(1), q.closest, atol=1e-12)
    # Inside = generalized winding number > 0.5 (points off the surface).
    off = dist > 1e-5
    assert torch.equal(q.inside[off], (wn > 0.5)[off])
    assert torch.equal(q.signed_distance[off] < 0, q.inside[off])
    # Normals: unit, and the signed gradient direction of the distance.
    assert torch.allclose(q.normal.norm(dim=-1), torch.ones(len(x), dtype=torch.float64), atol=1e-12)
    s = torch.where(q.inside, -1.0, 1.0).to(torch.float64)
    expected_n = s[:, None] * (x - q.closest) / dist[:, None]
    assert torch.allclose(q.normal[off], expected_n[off], atol=1e-5)


@pytest.mark.parametrize("name", list(MESHES))
def test_a_walk_from_the_faces_of_a_small_move_ago_finds_the_closest_faces(name):
    """query(near=faces of an earlier query) walks from them to the closest faces: after a move of
    a fraction of an edge, the distances of brute force over all faces, and the BVH search's
    closest points, normals and inside flags; after a move of several edges, a face at least as
    close as the one it started from."""
    verts, faces = MESHES[name]()
    surface = BodySurface(verts, faces)
    x0 = sample_points(verts, faces, 600, 0, seed=3, offset=0.02)
    start = surface.query(x0).face
    g = torch.Generator().manual_seed(4)
    x1 = x0 + 2e-3 * torch.randn(x0.shape, generator=g, dtype=x0.dtype)
    walked, searched = surface.query(x1, near=start), surface.query(x1)
    dist, _, _, gap = brute_force_closest(x1, verts, faces)
    assert not torch.equal(walked.face, start)  # the walk moved
    torch.testing.assert_close(walked.signed_distance.abs(), dist, atol=1e-12, rtol=0)
    clear = gap > 1e-4
    assert clear.sum() > 0.3 * len(x1)
    for field in ("closest", "normal", "signed_distance", "inside"):
        torch.testing.assert_close(getattr(walked, field)[clear], getattr(searched, field)[clear], atol=1e-12, rtol=0)
    x2 = x0 + 0.05 * torch.randn(x0.shape, generator=g, dtype=x0.dtype)
    far = surface.query(x2, near=start)
    from_start = surface.query(x2, near=start).closest
    corners = verts[faces[start]]
    start_dist = closest_point_on_triangle(x2, corners[:, 0], corners[:, 1], corners[:, 2])[0]
    assert ((x2 - far.closest).norm(dim=-1) <= (x2 - start_dist).norm(dim=-1) + 1e-12).all()
    assert torch.equal(far.closest, from_start)  # deterministic
    assert ((x2 - far.closest).norm(dim=-1) < (x2 - start_dist).norm(dim=-1) - 1e-3).any()


def test_open_mesh_winding_number_is_robust():
    """A sphere with a hole: inside follows the generalized winding number, not ray parity."""
    verts, faces = icosphere(3)
    centroids = verts[faces].mean(1)
    faces = faces[centroids[:, 1] < 0.14]  # open a small cap at the top
    x = sample_points(verts, faces, 300, 300, seed=2)
    q = query_body_surface(x, verts, faces)
    wn = brute_force_winding_number(x, verts, faces)
    dist = brute_force_closest(x, verts, faces)[0]
    clear = (dist > 1e-4) & ((wn - 0.5).abs() > 0.02)
    assert clear.sum() > 400
    assert torch.equal(q.inside[clear], (wn > 0.5)[clear])
    assert q.inside[x.norm(dim=-1) < 0.1].all()


def test_interpenetrating_parts_inside_follows_winding_number():
    """Two overlapping spheres in one mesh (like posed limbs pressed into the torso): the
    pseudo-normal sign is wrong inside the overlap, so the winding number decides there; away
    from it the surface is clean and no winding number is evaluated."""
    verts, faces = overlapping_spheres()
    x = sample_points(verts, faces, 1500, 500, seed=4, offset=0.06)
    surface = BodySurface(verts, faces)
    few = surface.query(x[:100])  # fewer points than body vertices: the winding number of each
    assert surface._doubtful is None
    q = surface.query(x)  # then the doubtful faces, found once
    assert surface._doubtful is not None
    assert torch.equal(few.inside, q.inside[:100])
    wn = brute_force_winding_number(x, verts, faces)
    dist = brute_force_closest(x, verts, faces)[0]
    clear = (dist > 1e-5) & ((wn - 0.5).abs() > 0.02)
    assert torch.equal(q.inside[clear], (wn > 0.5)[clear])
    pseudo = BodySurface(verts, faces, sign_method=SignMethod.PSEUDO_NORMAL).query(x)
    assert (pseudo.inside[clear] != (wn > 0.5)[clear]).sum() > 10  # the overlap does fool the pseudo-normal
    doubtful = surface.doubtful_faces()[0]
    centroids = verts[faces].mean(1)
    assert doubtful[(centroids[:, 0] > 0.095) & (centroids[:, 0] < 0.15)].all()  # around the overlap
    assert not doubtful[centroids[:, 0] < -0.05].any()  # the far side of the big sphere is clean


def test_buried_vertices_found_by_rays_then_winding_numbers_equal_winding_numbers_of_all():
    """On a closed surface a probe whose outward ray crosses nothing has winding number 0, and
    one whose ray first enters the surface head on is outside: the doubtful faces found with that
    filter are those the winding number of every probe gives, each face within DOUBT_REACH times
    its and the buried vertex's edges of one (overlapping spheres, and the same with a hole, where
    every probe gets its winding number)."""
    from physdrape.geometry.doubtful_faces import DOUBT_REACH, ENTERING, PROBE_OFFSET

    verts, closed = overlapping_spheres()
    holed = closed[verts[closed].mean(1)[:, 1] < 0.14]  # a hole in the big sphere's cap: no ray filter

    def by_winding_numbers_of_all(faces):
        surface = BodySurface(verts, faces)
        normals = surface._vertex_pseudo_normals()[0]
        probe = (verts + PROBE_OFFSET * normals).float().contiguous()
        owner = torch.zeros(len(verts), dtype=torch.int32)
        buried = surface.search(probe, owner, winding=True)[1]
        buried[surface._border] = True
        reach = torch.zeros(len(verts), dtype=verts.dtype)  # each vertex's longest edge among its faces
        for face in faces.tolist():
            for a, b in ((0, 1), (1, 2), (2, 0)):
                length = float((verts[face[a]] - verts[face[b]]).norm())
                for corner in face:
                    reach[corner] = max(float(reach[corner]), length)
        near = torch.zeros(len(verts), dtype=torch.bool)
        for v in torch.nonzero(buried)[:, 0].tolist():
            near |= (verts - verts[v]).norm(dim=-1) <= DOUBT_REACH * (reach + reach[v])
        return near[faces].any(dim=-1), buried, surface, probe, owner, normals

    expected, buried, surface, probe, owner, normals = by_winding_numbers_of_all(closed)
    assert buried.sum() > 10  # the vertices of each sphere inside the other
    hits, facing = surface._bvh.ray_hits(probe, owner, normals.float().contiguous())
    asked = hits & (facing > -ENTERING)
    assert not (buried & ~asked).any() and (~hits).sum() > len(verts) // 2  # the filter skips most, no buried one
    assert (hits & ~asked).any()  # rays entering the other sphere: no winding number
    assert torch.equal(surface.doubtful_faces()[0], expected)
    assert torch.equal(BodySurface(verts, holed).doubtful_faces()[0], by_winding_numbers_of_all(holed)[0])


def test_probes_whose_rays_enter_another_part_get_no_winding_number():
    """A small sphere 3 cm above a big one (an arm over the torso): the rays of the big sphere's
    probes under it enter the small sphere head on and are not asked about; nothing is buried and
    no face is doubtful, as the winding number of every probe says."""
    from physdrape.geometry.doubtful_faces import ENTERING, PROBE_OFFSET

    a_verts, a_faces = icosphere(3, 0.15)
    b_verts, b_faces = icosphere(3, 0.05)
    verts = torch.cat([a_verts, b_verts + torch.tensor([0.0, 0.23, 0.0], dtype=torch.float64)])
    surface = BodySurface(verts, torch.cat([a_faces, b_faces + len(a_verts)]))
    normals = surface._vertex_pseudo_normals()[0]
    probe = (verts + PROBE_OFFSET * normals).float().contiguous()
    owner = torch.zeros(len(verts), dtype=torch.int32)
    hits, facing = surface._bvh.ray_hits(probe, owner, normals.float().contiguous())
    assert (hits & (facing < -ENTERING)).sum() > 20 and not (hits & (facing > -ENTERING)).any()
    assert not surface.search(probe, owner, winding=True)[1].any()
    assert not surface.doubtful_faces().any()


def test_inside_is_the_winding_number_inside_flag_of_query():
    verts, faces = overlapping_spheres()
    x = sample_points(verts, faces, 300, 100, seed=6, offset=0.06)
    assert torch.equal(BodySurface(verts, faces).inside(x), BodySurface(verts, faces).query(x).inside)
    with pytest.raises(ValueError, match="WINDING_NUMBER"):
        BodySurface(verts, faces, sign_method=SignMethod.PSEUDO_NORMAL).inside(x)


def test_a_bound_decides_the_side_of_points_in_doubt_that_cannot_have_crossed(winding_searches):
    """Overlapping spheres (points near the overlap are in doubt): queried again after a small
    move with the first query's bound, the points in doubt that moved less than their distance
    get no winding number, and every field is the one the query without the bound gives."""
    from physdrape.geometry.distance_bound import DistanceBound

    verts, faces = overlapping_spheres()
    x = sample_points(verts, faces, 1500, 500, seed=8, offset=0.02)
    surface = BodySurface(verts, faces)
    surface.doubtful_faces()
    bound = DistanceBound.of(x, surface.query(x).signed_distance)
    moved = x + 1e-3 * torch.nn.functional.normalize(torch.randn(x.shape, generator=torch.Generator().manual_seed(2),
                                                                 dtype=torch.float64), dim=-1)
    winding_searches.clear()
    plain = surface.query(moved)
    with_bound = surface.query(moved, bound=bound)
    asked = winding_searches
    assert len(asked) == 2 and 0 < asked[1] < asked[0] // 4  # most points in doubt are certified
    for field in ("closest", "normal", "signed_distance", "face", "inside"):
        assert torch.equal(getattr(plain, field), getattr(with_bound, field)), field


def test_a_surface_told_of_its_workload_finds_its_doubtful_faces_first():
    verts, faces = icosphere(3, 0.15)
    told_little, told_much = BodySurface(verts, faces), BodySurface(verts, faces)
    told_little.expect(len(verts) // 2)  # fewer points than body vertices: winding numbers are cheaper
    assert told_little._doubtful is None
    told_much.expect(len(verts))
    assert told_much._doubtful is not None
    x = sample_points(verts, faces, 300, 100, seed=5)
    assert torch.equal(told_little.query(x).inside, told_much.query(x).inside)
    pseudo = BodySurface(verts, faces, sign_method=SignMethod.PSEUDO_NORMAL)
    pseudo.expect(10 * len(verts))  # no winding numbers at all: nothing to find
    assert pseudo._doubtful is None


def test_a_query_again_searches_only_the_points_that_moved(monkeypatch):
    from physdrape.geometry.body_bvh import BodyBVH

    verts, faces = bumpy_blob()
    surface = BodySurface(verts, faces)
    x = sample_points(verts, faces, 300, 100, seed=6)
    first = surface.query(x)
    searched = []
    search = BodyBVH.closest_faces

    def counting(self, points, body, **kwargs):
        if not kwargs.get("reuse") and not kwargs.get("winding"):
            searched.append(len(points))  # the closest-face searches that run
        return search(self, points, body, **kwargs)

    monkeypatch.setattr(BodyBVH, "closest_faces", counting)
    moved = x.clone()
    moved[:7] += 0.02
    again = surface.query(moved)
    assert searched == [7]
    fresh = BodySurface(verts, faces).query(moved)
    for field in ("closest", "normal", "signed_distance", "face", "bary", "inside"):
        assert torch.equal(getattr(again, field), getattr(fresh, field)), field
    assert torch.equal(surface.query(x).face, first.face)
    surface.update(verts * 1.01)  # the body moved: nothing is reused
    searched.clear()
    surface.query(x)
    assert searched == [len(x)]
    surface.forget_recent()  # nor after being told to forget
    searched.clear()
    surface.query(x)
    assert searched == [len(x)]


def test_gradients_match_finite_differences():
    verts, faces = bumpy_blob()
    x = sample_points(verts, faces, 160, 40, seed=3)
    dist, _, _, gap = brute_force_closest(x, verts, faces)
    x = x[(gap > 2e-4) & (dist > 1e-3)][:24]
    assert len(x) >= 10
    surface = BodySurface(verts, faces)

    def signed_distance(pts):
        return surface.query(pts).signed_distance

    def closest(pts):
        return surface.query(pts).closest

    xr = x.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(signed_distance, (xr,), eps=1e-6, atol=1e-6)
    assert torch.autograd.gradcheck(closest, (xr,), eps=1e-6, atol=1e-6)
    # The finite-difference signal is not zero: d moves along n at unit rate.
    grad = torch.autograd.grad(signed_distance(xr).sum(), xr)[0]
    assert torch.allclose(grad, surface.query(x).normal, atol=1e-10)
    assert grad.norm(dim=-1).min() > 0.99


def test_gradients_wrt_body_verts_match_finite_differences():
    verts, faces = icosphere(1)
    x = sample_points(verts, faces, 16, 4, seed=4)
    dist, _, _, gap = brute_force_closest(x, verts, faces)
    x = x[(gap > 2e-4) & (dist > 1e-3)][:8]
    assert len(x) >= 4
    vr = verts.clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda v: query_body_surface(x, v, faces).signed_distance, (vr,),
                                    eps=1e-6, atol=1e-6)


def test_a_surface_reads_its_current_vertices_after_update_and_in_a_graph():
    verts, faces = bumpy_blob()
    x = sample_points(verts, faces, 200, 50, seed=8)
    surface = BodySurface(verts, faces)
    surface.query(x)  # keeps the vertices in the kernels' types
    surface.update(verts * 1.01)
    assert torch.equal(surface.query(x).closest, BodySurface(verts * 1.01, faces).query(x).closest)
    vr = verts.clone().requires_grad_(True)
    in_graph = BodySurface(vr, faces)
    in_graph.query(x).signed_distance.sum().backward()
    first, vr.grad = vr.grad.clone(), None
    in_graph.query(x).signed_distance.sum().backward()  # a second query still reaches the vertices
    assert first.abs().sum() > 0 and torch.equal(vr.grad, first)


@pytest.mark.parametrize("name", list(MESHES))
def test_handler_step_clears_margin(name):
    """x* = x + relu(eps - d) n puts every point at d >= eps in one step (delta = 1).

    Exact where the surface is convex; at a concave crease of angle theta between two faces the
    neighbouring face can be up to eps (1 - cos theta) closer (the polyhedral limit, tiny on a
    fine body mesh), which is what the bound allows.
    """
    verts, faces = MESHES[name]()
    x = sample_points(verts, faces, 800, 100, seed=5, offset=0.01)
    # Also points exactly on vertices, edges midpoints and faces.
    x = torch.cat([x, verts[:50], verts[faces[:50]].mean(1), verts[faces[:50, :2]].mean(1)])
    surface = BodySurface(verts, faces)
    q = surface.query(x)
    x_new = x + torch.relu(EPS - q.signed_distance)[:, None] * q.normal
    d_new = surface.query(x_new).signed_distance
    crease = float(trimesh.Trimesh(verts.numpy(), faces.numpy(), process=False).face_adjacency_angles.max())
    slack = EPS * (1 - math.cos(crease)) if name != "icosphere" else 0.0
    assert d_new.min() >= EPS - slack - 1e-9, (float(d_new.min()), slack)
    assert (x_new - x)[q.signed_distance >= EPS].abs().max() == 0  # points already clear stay put


def test_batch_equals_singles_and_packed():
    bodies = [icosphere(2), icosphere(2), icosphere(2)]
    verts = torch.stack([bodies[0][0], bodies[1][0] * 1.3 + 0.05, bodies[2][0] * 0.8 - 0.02])
    faces = bodies[0][1]
    g = torch.Generator().manual_seed(6)
    x = (torch.rand(3, 200, 3, generator=g, dtype=torch.float64) * 2 - 1) * 0.25
    batch = BodySurface(verts, faces).query(x)
    packed = BodySurface(verts, faces).query(x.reshape(-1, 3), body_index=torch.arange(3).repeat_interleave(200))
    for b in range(3):
        single = BodySurface(verts[b], faces).query(x[b])
        for field in SurfaceQuery.__dataclass_fields__:
            got, want = getattr(batch, field)[b], getattr(single, field)
            assert torch.equal(got, want), field
            assert torch.equal(getattr(packed, field)[b * 200:(b + 1) * 200], want), field


def test_refit_equals_rebuild():
    verts, faces = torus()
    surface = BodySurface(verts, faces)
    moved = verts @ torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64) * 1.1
    moved = moved + torch.tensor([0.05, 0.1, -0.02], dtype=torch.float64)
    surface.update(moved)
    x = sample_points(moved, faces, 300, 100, seed=7)
    refit, fresh = surface.query(x), BodySurface(moved, faces).query(x)
    assert torch.equal(refit.inside, fresh.inside)
    assert torch.allclose(refit.signed_distance, fresh.signed_distance, atol=1e-7)
    # Different BVH layouts may break exact ties (edges, vertices) differently; elsewhere equal.
    clear = brute_force_closest(x, moved, faces)[3] > 1e-4
    assert torch.equal(refit.face[clear], fresh.face[clear])


def test_on_surface_points_use_pseudo_normals():
    verts, faces = icosphere(2)
    q = BodySurface(verts, faces).query(verts)  # exactly on vertices
    assert torch.allclose(q.signed_distance, torch.zeros(len(verts), dtype=torch.float64), atol=1e-12)
    assert torch.allclose(q.normal, angle_weighted_vertex_normals(verts, faces), atol=1e-12)
    assert ((q.normal * verts).sum(-1) > 0).all()  # outward


def test_dtype_follows_input_float32():
    verts, faces = icosphere(2)
    x = sample_points(verts, faces, 100, 20, seed=8)
    q32 = query_body_surface(x.float(), verts.float(), faces)
    q64 = query_body_surface(x, verts, faces)
    assert q32.signed_distance.dtype == torch.float32 and q32.normal.dtype == torch.float32
    assert torch.allclose(q32.signed_distance.double(), q64.signed_distance, atol=1e-5)


def test_bad_inputs_raise_clear_errors():
    verts, faces = icosphere(1)
    surface = BodySurface(verts, faces)
    with pytest.raises(ValueError, match="NaN"):
        surface.query(torch.tensor([[0.0, 0.0, float("nan")]], dtype=torch.float64))
    with pytest.raises(ValueError, match="last dimension of 3"):
        surface.query(torch.zeros(5, 2, dtype=torch.float64))
    with pytest.raises(TypeError, match="dtype"):
        surface.query(torch.zeros(5, 3, dtype=torch.float32))
    with pytest.raises(ValueError, match=r"must be in \[0, 42\) \(got 42\)"):
        BodySurface(verts, torch.tensor([[0, 1, 42]]))
    with pytest.raises(ValueError, match="shape"):
        BodySurface(verts, faces[:, :2])
    with pytest.raises(ValueError, match="NaN"):
        BodySurface(torch.full_like(verts, float("nan")), faces)
    with pytest.raises(ValueError, match="B = 2"):
        BodySurface(verts, faces).query(torch.zeros(2, 4, 3, dtype=torch.float64))
    batch = BodySurface(torch.stack([verts, verts]), faces)
    with pytest.raises(ValueError, match="body_index"):
        batch.query(torch.zeros(4, 3, dtype=torch.float64))
    with pytest.raises(ValueError, match=r"must be in \[0, 2\)"):
        batch.query(torch.zeros(4, 3, dtype=torch.float64), body_index=torch.tensor([0, 1, 2, 0]))
    with pytest.raises(ValueError, match="topology"):
        surface.update(verts[:-1])
    points = torch.zeros(4, 3, dtype=torch.float64)
    with pytest.raises(ValueError, match=r"one body face index per point, shape \(4,\)"):
        surface.query(points, near=torch.zeros(3, dtype=torch.int64))
    with pytest.raises(ValueError, match=rf"must be in \[0, {len(faces)}\)"):
        surface.query(points, near=torch.tensor([0, 1, len(faces), 2]))


@pytest.mark.anny
@pytest.mark.slow
def test_anny_canonical_body_matches_brute_force(request):
    try:
        body = request.getfixturevalue("anny_body")
    except pytest.FixtureLookupError:
        pytest.skip("anny_body fixture not available yet")
    verts = body.canonical_verts().to(torch.float64)
    faces = torch.as_tensor(body.faces)
    x = sample_points(verts, faces, 75, 25, seed=9, offset=0.02)
    q = BodySurface(verts, faces).query(x)
    for chunk in range(0, len(x), 50):
        xs = x[chunk:chunk + 50]
        dist = brute_force_closest(xs, verts, faces)[0]
        wn = brute_force_winding_number(xs, verts, faces)
        assert torch.allclose(q.signed_distance[chunk:chunk + 50].abs(), dist, atol=1e-6)
        off = dist > 1e-5
        assert torch.equal(q.inside[chunk:chunk + 50][off], (wn > 0.5)[off])


@pytest.mark.parametrize("sign_method", list(SignMethod))
def test_search_split_over_threads_is_bit_identical(sign_method):
    verts, faces = torus()
    x = sample_points(verts, faces, 3000, 1000, seed=3)
    single = BodySurface(verts, faces, sign_method=sign_method, search_threads=1).query(x)
    split = BodySurface(verts, faces, sign_method=sign_method, search_threads=3).query(x)
    for field in ("face", "inside", "closest", "signed_distance", "normal"):
        assert torch.equal(getattr(single, field), getattr(split, field)), field
    with pytest.raises(ValueError, match="search_threads"):
        BodySurface(verts, faces, search_threads=0)


def test_selected_body_equals_a_surface_of_that_body_alone():
    verts, faces = MESHES["bumpy"]()
    batch = torch.stack([verts, verts * 1.1 + 0.02])
    surface = BodySurface(batch, faces)
    x = sample_points(verts, faces, 900, 300, seed=5)
    for index in range(2):
        alone = BodySurface(batch[index], faces).query(x)
        one = surface.select(index).query(x)
        for field in ("closest", "normal", "signed_distance", "face", "inside"):
            assert torch.equal(getattr(one, field), getattr(alone, field)), field
    assert surface._doubtful is not None  # found once, for the batch, through the selections
