"""Layer pairs of a multi-piece garment (`garments.layering`) on a toy body."""

import numpy as np

from physdrape.garments.layering import layer_pairs


def _cube(half: float = 0.1):
    v = np.array([[x, y, z] for x in (-half, half) for y in (-half, half) for z in (-half, half)], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def _outward(v, f):
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    c = v[f].mean(1)
    return f if np.all((n * c).sum(1) > 0) else f[:, ::-1]


def test_each_vertex_is_paired_with_its_nearest_vertices_of_the_other_piece():
    """Two grids over the cube's top face, 5 mm and 15 mm above it, the outer one shifted by a
    third of a cell: every outer vertex within reach gets its k nearest inner vertices, in
    [outer, inner] order, and vice versa."""
    body_v, body_f = _cube()
    body_f = _outward(body_v, body_f)
    g = np.linspace(-0.06, 0.06, 7)
    xx, zz = np.meshgrid(g, g, indexing="ij")
    grid = np.stack([xx.ravel(), np.zeros(xx.size), zz.ravel()], 1)
    inner = grid + [0.0, 0.105, 0.0]
    outer = grid + [0.0067, 0.115, 0.0067]
    verts = np.concatenate([inner, outer])
    piece = np.repeat([0, 1], len(grid))
    one = layer_pairs(verts, piece, body_v, body_f, neighbours=1).pairs
    three = layer_pairs(verts, piece, body_v, body_f, neighbours=3)
    separation = three.separation
    three = three.pairs
    for pairs in (one, three):
        assert np.all(piece[pairs[:, 0]] == 1) and np.all(piece[pairs[:, 1]] == 0)  # outer over inner
    assert len(three) > len(one)
    np.testing.assert_allclose(separation, 0.01, atol=1e-9)  # authored 1 cm apart above the top face
    o = 24  # an outer vertex in the middle of the grid
    dist = np.linalg.norm(inner - outer[o], axis=1)
    nearest = set(np.argsort(dist)[:3].tolist())
    assert nearest <= set(three[three[:, 0] == len(grid) + o, 1].tolist())
    assert int(np.argmin(dist)) in one[one[:, 0] == len(grid) + o, 1]
    assert not nearest <= set(one[one[:, 0] == len(grid) + o, 1].tolist())
    far = layer_pairs(verts + np.repeat([[0, 0, 0], [0, 0.1, 0]], len(grid), 0), piece, body_v, body_f)
    assert len(far.pairs) == 0 and len(far.separation) == 0  # beyond the 4 cm radius nothing is paired


def _two_grids(outer_height):
    """An inner grid 5 mm over the cube's top face and an outer one (shifted by a third of a cell)
    at `outer_height(x, z)` [m] over it."""
    body_v, body_f = _cube()
    g = np.linspace(-0.06, 0.06, 7)
    xx, zz = np.meshgrid(g, g, indexing="ij")
    grid = np.stack([xx.ravel(), np.zeros(xx.size), zz.ravel()], 1)
    inner = grid + [0.0, 0.105, 0.0]
    outer = grid + [0.0067, 0.0, 0.0067]
    outer[:, 1] = 0.1 + outer_height(outer[:, 0], outer[:, 2])
    return np.concatenate([inner, outer]), np.repeat([0, 1], len(grid)), body_v, _outward(body_v, body_f)


def test_pieces_that_agree_order_all_their_near_pairs():
    """The outer grid lies 1 cm over the inner one except along one edge, where it comes level
    with it (side by side) and at a corner 2 mm under it (where a hem meets a waistband): the pieces agree
    on their order elsewhere, so those vertices are paired as outer too, with their (negative)
    template separation; without the consensus they would be left unpaired or put inside."""
    verts, piece, body_v, body_f = _two_grids(lambda x, z: np.where(x < 0.05, 0.015, np.where(z > 0.03, 0.003, 0.005)))
    pairs, separation, over, _ = layer_pairs(verts, piece, body_v, body_f)
    np.testing.assert_array_equal(over, [[False, False], [True, False]])  # piece 1 lies over piece 0
    assert np.all(piece[pairs[:, 0]] == 1) and np.all(piece[pairs[:, 1]] == 0)
    edge = np.flatnonzero((piece == 1) & (verts[:, 0] > 0.05))
    assert set(edge.tolist()) <= set(pairs[:, 0].tolist())  # every edge vertex is held outside
    np.testing.assert_allclose(separation, verts[pairs[:, 0], 1] - verts[pairs[:, 1], 1], atol=1e-9)
    assert separation.min() < 0
    strict = layer_pairs(verts, piece, body_v, body_f, consensus=1.01).pairs  # no consensus: per vertex
    assert not set(edge.tolist()) <= set(strict[:, 0].tolist())
    assert np.any(piece[strict[:, 0]] == 0)  # where the grid dips under, the order flips


def test_interleaved_pieces_keep_the_per_vertex_order():
    """Half of the outer grid lies 1 cm over the inner one and half 5 mm under it (a shirt tucked
    in at the front and out at the back): no consensus, each pair is ordered by its own body
    distances."""
    verts, piece, body_v, body_f = _two_grids(lambda x, z: np.where(x > 0.0, 0.0, 0.015))
    pairs, separation, over, _ = layer_pairs(verts, piece, body_v, body_f)
    assert not over.any()
    assert np.any(piece[pairs[:, 0]] == 0) and np.any(piece[pairs[:, 0]] == 1)
    assert np.all(separation > 0)  # each pair outer by its own distance to the body
