"""Edges, hinges and boundary loops of golden tiny meshes."""

import numpy as np
import torch

from physdrape.geometry import topology
from physdrape.geometry.normals import vertex_face_table
from physdrape.geometry.primitives import grid_sheet, open_cylinder


def test_two_triangles():
    faces = np.array([[0, 1, 2], [2, 1, 3]])
    np.testing.assert_array_equal(topology.undirected_edges(faces), [[0, 1], [0, 2], [1, 2], [1, 3], [2, 3]])
    hinges = topology.interior_hinges(faces)
    assert hinges.shape == (1, 4)
    assert set(hinges[0, :2]) == {1, 2} and set(hinges[0, 2:]) == {0, 3}
    loops = topology.boundary_loops(faces)
    assert len(loops) == 1 and sorted(loops[0].tolist()) == [0, 1, 2, 3]
    edge_index = topology.bidirectional_edges(topology.undirected_edges(faces))
    assert edge_index.shape == (2, 10)


def test_hinge_faces_hold_the_hinges_corners_in_order():
    """Each interior hinge's first face holds the half-edge v0 -> v1 and v2, its second v1 -> v0 and
    v3, on a tube (every face consistently wound)."""
    _, faces = open_cylinder(4, 8)
    hinges, two = topology.interior_hinges(faces), topology.interior_hinge_faces(faces)
    assert two.shape == (len(hinges), 2) and bool((two[:, 0] != two[:, 1]).all())
    for (v0, v1, v2, v3), (s, t) in zip(hinges.tolist(), two.tolist()):
        first, second = faces[s].tolist(), faces[t].tolist()
        assert set(first) == {v0, v1, v2} and set(second) == {v0, v1, v3}
        assert first[(first.index(v0) + 1) % 3] == v1 and second[(second.index(v1) + 1) % 3] == v0


def test_edges_are_found_once_per_face_content_and_shared_read_only():
    _, faces = open_cylinder(4, 8)
    edges = topology.undirected_edges(faces)
    again = topology.undirected_edges(faces.astype(np.int32).copy())  # the same faces, another array and dtype
    np.testing.assert_array_equal(again, edges)
    assert topology.digest(faces) == topology.digest(faces.astype(np.int32))
    flipped = faces[:, [0, 2, 1]]
    assert topology.digest(flipped) != topology.digest(faces)
    # what is kept is shared: the grouped half-edges cannot be written by a caller
    groups = topology._edge_groups(faces)
    assert groups is topology._edge_groups(faces.copy())
    assert all(not value.flags.writeable for value in groups if isinstance(value, np.ndarray))
    # a mesh of other faces gets its own
    _, other = open_cylinder(3, 6)
    assert len(topology.undirected_edges(other)) != len(edges)
    boundary = topology.boundary_edges(flipped)
    np.testing.assert_array_equal(np.sort(boundary, axis=1), np.sort(topology.boundary_edges(faces), axis=1))
    assert not (boundary == topology.boundary_edges(faces)).all()  # each in its own winding


def test_tube_has_two_boundary_loops_and_euler_characteristic_zero():
    verts, faces = open_cylinder(4, 8)
    loops = topology.boundary_loops(faces)
    assert sorted(len(loop) for loop in loops) == [8, 8]
    num_edges = len(topology.undirected_edges(faces))
    assert len(verts) - num_edges + len(faces) == 0  # an annulus
    assert len(topology.interior_hinges(faces)) == num_edges - 16


def test_boundary_loop_is_walked_in_order():
    _, faces = grid_sheet(3, 4)
    (loop,) = topology.boundary_loops(faces)
    boundary = {tuple(sorted(e)) for e in topology.boundary_edges(faces).tolist()}
    steps = {tuple(sorted((int(a), int(b)))) for a, b in zip(loop, np.roll(loop, -1))}
    assert steps == boundary


def test_components():
    _, f1 = grid_sheet(2, 2)
    faces = np.vstack([f1, f1 + 4])
    labels = topology.connected_components(8, faces)
    assert len(set(labels[:4])) == 1 and len(set(labels[4:])) == 1 and labels[0] != labels[4]
    assert len(topology.non_manifold_edges(faces)) == 0


def test_coarse_graphs_halve_the_nodes_double_the_edges_and_stay_connected():
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    verts, faces = grid_sheet(33, 33, width=1.0, height=1.0)
    edges = topology.undirected_edges(faces)
    levels = topology.coarse_graphs(edges, len(verts), 3)
    assert len(levels) == 3
    nodes, length = np.arange(len(verts)), np.median(np.linalg.norm(verts[edges[:, 0]] - verts[edges[:, 1]], axis=1))
    mesh_length = length
    for coarse in levels:
        assert coarse.ndim == 2 and coarse.shape[1] == 2 and (coarse[:, 0] < coarse[:, 1]).all()
        level_nodes = np.unique(coarse)
        assert np.isin(level_nodes, nodes).all()  # each level keeps a subset of the previous one's nodes
        assert len(level_nodes) <= len(nodes) / 1.8
        local = np.searchsorted(level_nodes, coarse)
        graph = coo_matrix((np.ones(len(local)), (local[:, 0], local[:, 1])), shape=(len(level_nodes),) * 2)
        assert connected_components(graph, directed=False)[0] == 1
        new_length = np.median(np.linalg.norm(verts[coarse[:, 0]] - verts[coarse[:, 1]], axis=1))
        assert 1.3 < new_length / length < 3.0
        nodes, length = level_nodes, new_length
    assert length > 5 * mesh_length  # three levels: an edge spans ~6 mesh edges
    again = topology.coarse_graphs(edges, len(verts), 3)
    assert all(np.array_equal(a, b) for a, b in zip(levels, again))
    assert topology.coarse_graphs(edges, len(verts), 0) == []
    # a shallower hierarchy is a deeper one's start, built once and shared read-only; the same
    # levels as a build of exactly that depth
    shallower = topology.coarse_graphs(edges, len(verts), 2)
    assert len(shallower) == 2 and all(a is b for a, b in zip(levels, shallower))
    deeper = topology.coarse_graphs(edges, len(verts), 6)
    assert len(deeper) > 3 and all(np.array_equal(a, b) for a, b in zip(levels, deeper))
    assert not any(level.flags.writeable for level in levels + deeper)
    built = topology._coarsen(edges, len(verts), 2)
    assert all(np.array_equal(a, b) for a, (_, b) in zip(levels, built)) and len(built) == 2


def test_aggregates_partition_the_mesh_into_connected_patches():
    from scipy.sparse.csgraph import connected_components

    verts, faces = grid_sheet(33, 33, width=1.0, height=1.0)
    # plus a lone triangle (too small to keep a seed) and an isolated vertex: one patch each
    faces = np.concatenate([faces, [[len(verts), len(verts) + 1, len(verts) + 2]]])
    num_verts = len(verts) + 4
    edges = topology.undirected_edges(faces)
    label = topology.aggregates(edges, num_verts, 2)
    assert label.shape == (num_verts,) and label.min() == 0
    count = label.max() + 1
    assert set(np.unique(label)) == set(range(count))
    assert 100 < count < 300  # two levels: about 6 grid vertices per patch (measured 184 + 2 for 33² + 4)
    assert label[-4:-1].tolist() == [label[-4]] * 3 and label[-1] not in label[:-1]
    adjacency = topology.vertex_adjacency(num_verts, edges)
    for patch in range(count):  # each patch is connected through its own edges
        members = np.flatnonzero(label == patch)
        assert connected_components(adjacency[members][:, members], directed=False)[0] == 1
    assert np.array_equal(label, topology.aggregates(edges, num_verts, 2))


def test_smoothed_prolongation_is_a_smooth_partition_of_unity():
    verts, faces = grid_sheet(33, 33, width=1.0, height=1.0)
    edges = topology.undirected_edges(faces)
    label = topology.aggregates(edges, len(verts), 2)
    raw = topology.smoothed_prolongation(edges, len(verts), label, 0).toarray()
    assert np.array_equal(raw, np.eye(label.max() + 1)[label])  # no passes: the indicators
    p = topology.smoothed_prolongation(edges, len(verts), label, 2).toarray()
    assert (p >= 0).all()
    np.testing.assert_allclose(p.sum(1), 1.0, rtol=1e-12)
    # smoother: the jump of a patch's weight across a mesh edge is smaller than the indicator's
    jump = lambda m: np.abs(m[edges[:, 0]] - m[edges[:, 1]]).max(1).mean()
    assert jump(p) < 0.6 * jump(raw)


def test_face_rings_are_the_other_faces_at_a_faces_vertices():
    _, faces = grid_sheet(4, 3)
    faces = np.concatenate([faces, [[100, 101, 102]]])  # a lone face: an empty ring
    rings = topology.face_rings(faces, vertex_face_table(torch.from_numpy(faces), 103).numpy())
    num_faces = len(faces)
    for f, tri in enumerate(faces):
        want = sorted({g for g, other in enumerate(faces) if g != f and set(tri) & set(other)})
        got = rings[f][rings[f] < num_faces].tolist()
        assert got == want, f
    assert rings.shape[1] == max(len(r[r < num_faces]) for r in rings)
    assert topology.face_rings(np.zeros((0, 3), np.int64), np.zeros((0, 1), np.int64)).shape == (0, 0)


def test_narrow_band_order_is_a_permutation_no_wider_than_reverse_cuthill_mckee_or_the_identity():
    """A shuffled grid of patches with its diagonal neighbours (the coarse matrix's pattern), and
    the same with a second, disconnected grid: every node once, and a band no wider than scipy's
    reverse Cuthill–McKee or the given numbering."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import reverse_cuthill_mckee

    from physdrape.geometry.topology import narrow_band_order

    def grid(nx, ny, offset=0):
        ids = np.arange(nx * ny).reshape(nx, ny) + offset
        pairs = [(ids[i, j], ids[i + di, j + dj]) for i in range(nx) for j in range(ny)
                 for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)) if 0 <= i + di < nx and 0 <= j + dj < ny]
        return np.array(pairs)

    def width(order, rows, cols):
        new = np.empty_like(order)
        new[order] = np.arange(len(order))
        return np.abs(new[rows] - new[cols]).max()

    rng = np.random.default_rng(0)
    for pairs, n in ((grid(12, 30), 360), (np.concatenate([grid(12, 30), grid(5, 7, offset=360)]), 395)):
        shuffle = rng.permutation(n)
        pairs = shuffle[pairs]
        rows, cols = np.concatenate([pairs[:, 0], pairs[:, 1], np.arange(n)]), np.concatenate(
            [pairs[:, 1], pairs[:, 0], np.arange(n)])
        order = narrow_band_order(rows, cols, n)
        assert sorted(order.tolist()) == list(range(n))
        graph = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
        rcm = reverse_cuthill_mckee(graph, symmetric_mode=True)
        assert width(order, rows, cols) <= min(width(rcm, rows, cols), width(np.arange(n), rows, cols))
        assert width(order, rows, cols) < width(rcm, rows, cols)  # here narrower: 20 against 23 and 24
