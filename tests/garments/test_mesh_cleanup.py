"""Mesh clean-up after remeshing: short edges collapsed, ears removed, slivers flipped, topology kept."""

import numpy as np
import pytest

from physdrape.garments.mesh_cleanup import (
    collapse_short_edges,
    flip_to_delaunay,
    remove_flat_ears,
    repair_moved_mesh,
)
from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.topology import (
    boundary_loops,
    non_manifold_edges,
    undirected_edges,
)


def euler(v, f):
    return len(v) - len(undirected_edges(f)) + len(f)


def sheet(n=6):
    v, f = grid_sheet(n, n, width=1.0, height=1.0)  # the xz-plane
    return np.asarray(v, np.float64), np.asarray(f, np.int64)


def normals(v, f):
    return np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])


def test_short_interior_edge_collapses_and_keeps_topology():
    v, f = sheet()
    e = undirected_edges(f)
    inside = (v[:, 0] > 0) & (v[:, 0] < 1) & (v[:, 2] > 0) & (v[:, 2] < 1)
    interior = [k for k, (a, b) in enumerate(e) if inside[a] and inside[b]]
    a, b = e[interior[len(interior) // 2]]
    v = v.copy()
    v[b] = v[a] + 0.05 * (v[b] - v[a])  # a 1 % edge
    v2, f2 = collapse_short_edges(v, f, 0.05)
    assert len(v2) == len(v) - 1
    assert euler(v2, f2) == euler(v, f) and len(boundary_loops(f2)) == 1 and len(non_manifold_edges(f2)) == 0
    lengths = np.linalg.norm(v2[undirected_edges(f2)[:, 0]] - v2[undirected_edges(f2)[:, 1]], axis=1)
    assert lengths.min() > 0.05
    assert (normals(v2, f2)[:, 1] * normals(v, f)[0, 1] > 0).all()  # no face flipped


def test_short_boundary_edge_collapses_along_the_boundary():
    v, f = sheet()
    v = v.copy()
    corner_row = np.nonzero((v[:, 2] == 0) & (v[:, 0] > 0.3) & (v[:, 0] < 0.7))[0]
    a, b = corner_row[0], corner_row[1]
    v[b, 0] = v[a, 0] + 0.01
    v2, f2 = collapse_short_edges(v, f, 0.05)
    assert len(v2) == len(v) - 1
    assert len(boundary_loops(f2)) == 1 and euler(v2, f2) == euler(v, f)
    assert np.isclose(v2[:, 2].min(), 0.0) and (v2[:, 1] == 0).all()  # merged on the boundary line


def test_interior_edge_between_two_boundaries_is_not_collapsed():
    # A strip one triangle wide: every interior edge joins the two boundary rows.
    v, f = grid_sheet(2, 9, width=1.0, height=0.01)
    v, f = np.asarray(v, np.float64), np.asarray(f, np.int64)
    v2, f2 = collapse_short_edges(v, f, 0.02)
    assert len(boundary_loops(f2)) == 1 and len(non_manifold_edges(f2)) == 0


def test_flat_ear_is_removed_and_sharp_ear_kept():
    # Quad split into three faces, the boundary vertex 4 almost on the edge 1-2.
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [1.02, 0.5, 0], [0.5, 0.5, 0]], np.float64)
    f = np.array([[0, 1, 5], [1, 2, 5], [2, 3, 5], [3, 0, 5], [1, 4, 2]], np.int64)
    v2, f2 = remove_flat_ears(v, f)
    assert len(v2) == 5 and len(f2) == 4
    v[4, 0] = 1.6  # a real corner, not a flat ear
    assert len(remove_flat_ears(v, f)[1]) == 5


def test_flip_makes_a_flat_quad_delaunay():
    v = np.array([[0, 0, 0], [2, 0, 0], [1, 0.1, 0], [1, -0.1, 0]], np.float64)
    f = np.array([[0, 1, 2], [1, 0, 3]], np.int64)  # the long diagonal 0-1: two slivers
    f2 = flip_to_delaunay(v, f)
    assert {tuple(sorted(t)) for t in f2.tolist()} == {(0, 2, 3), (1, 2, 3)}
    assert (normals(v, f2)[:, 2] > 0).all() == (normals(v, f)[:, 2] > 0).all()


def test_flip_unfolds_a_sliver_folded_over_its_neighbour():
    # the sliver (0, 1, 2) has its far corner 2 just across the edge 0-1, over the big face (1, 0, 3)
    v = np.array([[0, 0, 0], [2, 0, 0], [1, -0.01, 0], [1, -1, 0]], np.float64)
    f = np.array([[0, 1, 2], [1, 0, 3]], np.int64)
    assert normals(v, f)[0, 2] < 0 < normals(v, f)[1, 2]  # folded
    np.testing.assert_array_equal(flip_to_delaunay(v, f), f)  # not coplanar: left by default
    f2 = flip_to_delaunay(v, f, fold_area_ratio=0.05)
    assert {tuple(sorted(t)) for t in f2.tolist()} == {(0, 2, 3), (1, 2, 3)}
    assert (normals(v, f2)[:, 2] > 0).all()  # both with the big face's orientation
    v[2, 1] = -0.5  # a fold of two faces of similar size (a hem turned back) is a shape, kept
    np.testing.assert_array_equal(flip_to_delaunay(v, f, fold_area_ratio=0.05), f)


def test_repair_after_moves_collapses_squeezed_edges_and_flips_slivers():
    v, f = sheet()
    e = undirected_edges(f)
    inside = (v[:, 0] > 0) & (v[:, 0] < 1) & (v[:, 2] > 0) & (v[:, 2] < 1)
    a, b = next((a, b) for a, b in e if inside[a] and inside[b])
    v = v.copy()
    v[b] = v[a] + 0.02 * (v[b] - v[a])  # a move squeezed an edge
    v2, f2 = repair_moved_mesh(v, f, min_edge=0.05)
    assert len(v2) == len(v) - 1 and euler(v2, f2) == euler(v, f)
    lengths = np.linalg.norm(v2[undirected_edges(f2)[:, 0]] - v2[undirected_edges(f2)[:, 1]], axis=1)
    assert lengths.min() > 0.05


def test_remeshed_garment_has_no_short_edges_or_slivers(tmp_path):
    pytest.importorskip("gpytoolbox")
    from physdrape.garments.generator import generate_valid_garment

    g, _ = generate_valid_garment("tanktop", seed=3)
    e = undirected_edges(g.faces)
    lengths = np.linalg.norm(g.verts[e[:, 0]] - g.verts[e[:, 1]], axis=1)
    area = 0.5 * np.linalg.norm(normals(g.verts, g.faces), axis=1)
    assert lengths.min() > 0.08 * np.median(lengths), lengths.min() / np.median(lengths)
    assert area.min() > 0.02 * np.median(area), area.min() / np.median(area)
