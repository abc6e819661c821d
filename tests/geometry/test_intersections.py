"""The garment-side queries: ray hits, self-intersections, and the numpy front-ends."""

import numpy as np
import pytest
import torch

from physdrape.garments.numpy_geometry import BodyDistance, vertex_normals
from physdrape.geometry.garment import vertex_normals as torch_vertex_normals
from physdrape.geometry.intersections import (
    piece_crossings,
    ray_hit_distances,
    self_intersecting_faces,
    self_intersecting_pairs,
)


def _cube(half=0.1):
    """A closed, outward-wound cube of side 2 * half [m]."""
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def test_ray_hit_distances():
    v, f = _cube()
    origins = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 0.5], [0.5, 0.5, 0.5]])
    dirs = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    t = ray_hit_distances(v, f, origins, dirs, max_t=2.0)
    np.testing.assert_allclose(t, [0.4, 2.0, 2.0], atol=1e-6)  # hit, pointing away, missing
    assert ray_hit_distances(v, f, np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)


def test_no_self_intersection_on_a_closed_cube():
    v, f = _cube()
    assert len(self_intersecting_faces(v, f)) == 0
    assert len(self_intersecting_faces(v, f[:0])) == 0


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_layered_triangles_a_few_millimetres_apart_do_not_intersect(scale):
    """A top's triangle over a waistband's, from a drape [m] (translated, rounded to 0.1 mm): each
    lies wholly on one side of the other's plane, 0.3–4 mm away, so they do not intersect, at any
    scale; a triangle pushed through the first does, at any scale. (Warp's triangle test snaps
    plane distances below an absolute 1e-6, in units of twice the area times the distance, to
    zero: unscaled, such centimetre triangles in metres read as touching.)"""
    top = np.array([[0.0, 0.0, 0.0], [-0.007, -0.0034, -0.0053], [0.0159, -0.0048, 0.0097]])
    band = np.array([[0.0246, -0.0058, 0.0106], [-0.0088, -0.0007, -0.0107], [0.0131, -0.0048, 0.0049]])
    normal = np.cross(top[1] - top[0], top[2] - top[0])
    normal /= np.linalg.norm(normal)
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    assert len(self_intersecting_pairs(np.concatenate([top, band]) * scale, faces)) == 0
    through = band - normal * ((band - top[0]) @ normal).mean()  # its centre moved onto the top's plane
    assert self_intersecting_pairs(np.concatenate([top, through]) * scale, faces).tolist() == [[0, 1]]


def test_piece_crossings_count_only_pairs_of_two_pieces():
    """Two flat squares (pieces) crossing each other at right angles: their faces intersect, and
    every such pair joins the two pieces; the same two squares as one piece count none, and so
    do the squares apart."""
    square = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]]) * 0.05
    upright = square[:, [0, 2, 1]]  # the square in the x-z plane, through the first
    verts = np.concatenate([square, upright])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    pairs = self_intersecting_pairs(verts, faces)
    assert len(pairs) > 0
    assert piece_crossings(verts, faces) == len(pairs)  # the connected components: two pieces
    assert piece_crossings(verts, faces, piece=np.zeros(8, np.int64)) == 0
    apart = np.concatenate([square, upright + [0.0, 0.5, 0.0]])
    assert piece_crossings(apart, faces) == 0


def test_piece_crossings_are_the_intersecting_pairs_between_pieces():
    """Three copies of a T-shirt, one scaled and one turned through the first, as three pieces: the
    count is that of the reference, every intersecting pair filtered to those of two pieces, and
    pairs within a piece (a copy folded through itself) are not counted."""
    from physdrape.api.specs import garment_template

    tee = garment_template("default")
    v, f = tee.verts, np.asarray(tee.faces, np.int64)
    turn = np.array([[np.cos(0.3), 0.0, np.sin(0.3)], [0.0, 1.0, 0.0], [-np.sin(0.3), 0.0, np.cos(0.3)]])
    centre = v.mean(0)
    verts = np.concatenate([v, (v - centre) * 0.97 + centre, (v - centre) @ turn.T + centre])
    faces = np.concatenate([f, f + len(v), f + 2 * len(v)])
    piece = np.repeat(np.arange(3), len(v))
    pairs = self_intersecting_pairs(verts, faces)
    owner = piece[faces[:, 0]]
    between = owner[pairs[:, 0]] != owner[pairs[:, 1]]
    assert between.sum() > 100 and len({(a, b) for a, b in zip(owner[pairs[:, 0]], owner[pairs[:, 1]])}) >= 3
    assert piece_crossings(verts, faces, piece) == between.sum()
    folded = verts.copy()
    folded[:len(v), 1] = centre[1] - np.abs(v[:, 1] - centre[1])  # the first copy folded through itself
    pairs = self_intersecting_pairs(folded, faces)
    within = owner[pairs[:, 0]] == owner[pairs[:, 1]]
    assert within.any()
    assert piece_crossings(folded, faces, piece) == (~within).sum()


def test_body_distance_sign_and_normal():
    v, f = _cube()
    d, closest, normal = BodyDistance(v, f)(np.array([[0.0, 0.0, 0.15], [0.0, 0.0, 0.05]]))
    np.testing.assert_allclose(d, [0.05, -0.05], atol=1e-12)  # negative inside
    np.testing.assert_allclose(closest, [[0, 0, 0.1], [0, 0, 0.1]], atol=1e-12)
    np.testing.assert_allclose(normal, [[0, 0, 1], [0, 0, 1]], atol=1e-12)


def test_numpy_vertex_normals_are_the_torch_ones():
    v, f = _cube()
    n = vertex_normals(v, f)
    assert n.dtype == np.float64 and n.shape == v.shape
    np.testing.assert_array_equal(n, torch_vertex_normals(torch.from_numpy(v), torch.from_numpy(f)).numpy())
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    assert ((n * v).sum(1) > 0).all()  # outward
