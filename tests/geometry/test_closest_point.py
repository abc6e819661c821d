"""The Warp closest-point kernel against its torch twin (`closest_point_reference`), values and
gradients, in every region of the triangle; the surface kernel's feature pseudo-normals, signs and
signed distances."""

import pytest
import torch
from closest_point_reference import closest_point_on_triangle as reference

from physdrape.geometry.closest_point import (
    closest_point_on_indexed_triangles,
    closest_point_on_triangle,
    closest_surface_points,
)


def _cases(num=3000, seed=0):
    """Random triangles and points around them (every Voronoi region is hit), plus points on the
    corners and edges themselves."""
    g = torch.Generator().manual_seed(seed)
    tri = torch.rand(num, 3, 3, generator=g, dtype=torch.float64)
    x = torch.rand(num, 3, generator=g, dtype=torch.float64) * 3 - 1
    x[:50] = tri[:50, 0]  # exactly on a corner
    x[50:100] = 0.5 * (tri[50:100, 1] + tri[50:100, 2])  # exactly on an edge
    return x, tri


def test_the_kernel_matches_the_torch_twin_in_every_region():
    x, tri = _cases()
    p, bary = closest_point_on_triangle(x, tri[:, 0], tri[:, 1], tri[:, 2])
    p_ref, bary_ref = reference(x, tri[:, 0], tri[:, 1], tri[:, 2])
    torch.testing.assert_close(p, p_ref, rtol=0, atol=1e-14)
    torch.testing.assert_close(bary, bary_ref, rtol=0, atol=1e-14)
    assert torch.equal(bary == 0, bary_ref == 0)  # the same exact zeros: the same feature
    zeros = (bary == 0).sum(-1)
    assert (zeros == 0).any() and (zeros == 1).any() and (zeros == 2).any()  # all three kinds of region


def test_the_gradients_are_the_torch_twins_and_pass_gradcheck():
    x, tri = _cases(num=2000, seed=1)
    weights = torch.randn(2, *x.shape, generator=torch.Generator().manual_seed(2), dtype=torch.float64)

    def loss(fn, x, tri):
        p, bary = fn(x, tri[:, 0], tri[:, 1], tri[:, 2])
        return (p * weights[0]).sum() + (bary * weights[1]).sum()

    xr, tr = x.clone().requires_grad_(True), tri.clone().requires_grad_(True)
    fast = torch.autograd.grad(loss(closest_point_on_triangle, xr, tr), (xr, tr))
    slow = torch.autograd.grad(loss(reference, xr, tr), (xr, tr))
    for a, b in zip(fast, slow):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
    few = slice(100, 120)  # away from region borders: finite differences stay in one region
    assert torch.autograd.gradcheck(lambda x, t: closest_point_on_triangle(x, t[:, 0], t[:, 1], t[:, 2]),
                                    (xr[few].detach().requires_grad_(), tr[few].detach().requires_grad_()))


def test_indexed_triangles_share_vertices_and_keep_the_dtype():
    verts = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0]], requires_grad=True)
    corners = torch.tensor([[0, 1, 2], [1, 3, 2]])
    points = torch.tensor([[0.2, 0.2, 0.5], [0.9, 0.9, -0.3]], requires_grad=True)
    p, bary = closest_point_on_indexed_triangles(points, verts, corners)
    assert p.dtype == torch.float32 and bary.dtype == torch.float32
    torch.testing.assert_close(p, torch.tensor([[0.2, 0.2, 0.0], [0.9, 0.9, 0.0]]))
    p.sum().backward()
    # the plane projection moves with the in-plane components of the points...
    torch.testing.assert_close(points.grad, torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0]]))
    # ...and the whole plane with its corners, each by its barycentric weight: a shared vertex sums both
    assert torch.allclose(verts.grad[:, 2].sum(), torch.tensor(2.0))
    with pytest.raises(TypeError, match="convert one of them"):
        closest_point_on_indexed_triangles(points.double(), verts, corners)
    with pytest.raises(RuntimeError, match="once"):
        q, _ = closest_point_on_indexed_triangles(points, verts, corners)
        torch.autograd.grad(q.sum(), points, create_graph=True)


def _one_triangle(points, near_tol):
    """`closest_surface_points` on the triangle (0, 0, 0), (1, 0, 0), (0, 1, 0) with made-up
    pseudo-normals: the face's +z, its edges' and its vertices' each a different unit vector."""
    verts = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], dtype=torch.float64)
    faces = torch.tensor([[0, 1, 2]], dtype=torch.int32)
    face_normals = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64)
    edge_normals = torch.tensor([[[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]]]], dtype=torch.float64)
    vertex_normals = torch.tensor([[[0.6, 0.8, 0.0], [0.0, 0.6, 0.8], [0.8, 0.0, 0.6]]], dtype=torch.float64)
    zero = torch.zeros(len(points), dtype=torch.int32)
    out = closest_surface_points(torch.tensor(points, dtype=torch.float64), verts, zero, zero, faces, face_normals,
                                 edge_normals, vertex_normals, near_tol=near_tol)
    return out, (face_normals, edge_normals, vertex_normals)


def test_pseudo_normals_are_picked_by_the_feature():
    # over the face, past each edge (opposite corners 0, 1, 2) and past corners 1 and 2
    points = [[0.2, 0.3, 0.5], [0.8, 0.8, 0.0], [-0.5, 0.5, 0.0], [0.5, -0.5, 0.0], [2.0, -1.0, 0.0], [-1.0, 2.0, 0.0]]
    out, (face_normals, edge_normals, vertex_normals) = _one_triangle(points, near_tol=10.0)  # all "on" it
    assert torch.equal((out.bary == 0).sum(-1), torch.tensor([0, 1, 1, 1, 2, 2]))
    expected = torch.stack([face_normals[0, 0], edge_normals[0, 0, 0], edge_normals[0, 0, 1], edge_normals[0, 0, 2],
                            vertex_normals[0, 1], vertex_normals[0, 2]])
    torch.testing.assert_close(out.normal, expected, rtol=0, atol=0)
    assert out.near.all()
    torch.testing.assert_close(out.signed_distance, ((torch.tensor(points, dtype=torch.float64) - out.closest)
                                                     * expected).sum(-1), rtol=0, atol=1e-15)


def test_off_the_surface_the_normal_points_out_and_the_distance_is_signed():
    out, _ = _one_triangle([[0.2, 0.3, 0.5], [0.2, 0.3, -0.25], [0.2, 0.3, 1e-9]], near_tol=1e-6)
    torch.testing.assert_close(out.normal, torch.tensor([[0.0, 0.0, 1.0]] * 3, dtype=torch.float64))
    torch.testing.assert_close(out.signed_distance, torch.tensor([0.5, -0.25, 1e-9], dtype=torch.float64))
    assert out.inside.tolist() == [False, True, False] and out.near.tolist() == [False, False, True]


def test_the_surface_kernels_gradients_pass_gradcheck():
    """Closest point, normal and signed distance w.r.t. the points and the triangle's corners,
    away from region borders (finite differences stay in one region)."""
    faces = torch.tensor([[0, 1, 2]], dtype=torch.int32)
    normals = (torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64), torch.zeros(1, 1, 3, 3, dtype=torch.float64),
               torch.zeros(1, 3, 3, dtype=torch.float64))
    points = torch.tensor([[0.2, 0.3, 0.5], [0.9, 0.8, 0.1], [1.5, -0.4, -0.3]], dtype=torch.float64, requires_grad=True)
    verts = torch.tensor([[0.0, 0.1, 0.0], [1.0, 0.0, 0.2], [0.1, 1.0, 0.0]], dtype=torch.float64, requires_grad=True)
    zero = torch.zeros(3, dtype=torch.int32)

    def outputs(x, v):
        out = closest_surface_points(x, v, zero, zero, faces, *normals, near_tol=1e-6)
        return out.closest, out.normal, out.signed_distance

    assert torch.autograd.gradcheck(outputs, (points, verts))


def test_the_surface_kernels_point_gradients_need_no_vertex_gradients():
    """With the bodies' vertices held constant (a training pool's bodies) the backward gives the
    points the gradients it gives them when the vertices' are asked too."""
    faces = torch.tensor([[0, 1, 2]], dtype=torch.int32)
    normals = (torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float64), torch.zeros(1, 1, 3, 3, dtype=torch.float64),
               torch.zeros(1, 3, 3, dtype=torch.float64))
    verts = torch.tensor([[0.0, 0.1, 0.0], [1.0, 0.0, 0.2], [0.1, 1.0, 0.0]], dtype=torch.float64)
    zero = torch.zeros(3, dtype=torch.int32)
    weights = torch.tensor([[0.3, -1.2, 0.7], [2.0, 0.1, -0.4], [-0.6, 0.9, 1.1]], dtype=torch.float64)
    grads = []
    for vertex_grads in (True, False):
        points = torch.tensor([[0.2, 0.3, 0.5], [0.9, 0.8, 0.1], [1.5, -0.4, -0.3]], dtype=torch.float64,
                              requires_grad=True)
        v = verts.clone().requires_grad_(vertex_grads)
        out = closest_surface_points(points, v, zero, zero, faces, *normals, near_tol=1e-6)
        ((out.closest * weights).sum() + (out.normal * weights).sum() + out.signed_distance.sum()).backward()
        assert (v.grad is not None) == vertex_grads
        grads.append(points.grad)
    assert grads[0].abs().sum() > 0
    torch.testing.assert_close(grads[1], grads[0], rtol=0, atol=0)
