"""Connectivity of a triangle mesh: edges, hinges, boundary loops (numpy, computed once per mesh)."""

from __future__ import annotations

import collections
import hashlib

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee, shortest_path

from physdrape.tensor_memo import KeyedMemo


def _half_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directed half-edges a→b of every face in winding order, their face and opposite corner.

    Returns:
        ab: (3F, 2) int64 half-edge endpoints; face: (3F,) owning face; opposite: (3F,) the third
        corner of that face.
    """
    faces = np.asarray(faces, dtype=np.int64)
    ab = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    opposite = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    face = np.tile(np.arange(len(faces), dtype=np.int64), 3)
    return ab, face, opposite


#: The edge groups of the most recently seen face arrays, by content: one garment's topology is
#: asked for by its transfer fit, its graph, its pieces, its closures and its coarse space in turn.
_EDGE_GROUPS = KeyedMemo(8)


def _edge_groups(faces: np.ndarray):
    """Half-edges grouped by undirected edge: (sorted ab, face, opposite, unique keys, start, count,
    number of vertices), read-only arrays (computed once per face array's content)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    return _EDGE_GROUPS.get((faces.shape, digest(faces)), lambda: _read_only(_group_edges(faces)))


def digest(array: np.ndarray) -> bytes:
    """A 16-byte digest of an index array's values (as int64, whatever its integer dtype), the
    key under which what is derived from a mesh's faces or edges is kept."""
    return hashlib.blake2b(np.ascontiguousarray(array, np.int64).view(np.uint8), digest_size=16).digest()


def _read_only(values: tuple) -> tuple:
    """`values` with every array among them made read-only (they are shared by every caller)."""
    for value in values:
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return values


def _group_edges(faces: np.ndarray):
    """`_edge_groups`, computed."""
    ab, face, opposite = _half_edges(faces)
    num_verts = int(faces.max()) + 1 if len(faces) else 0
    lo, hi = ab.min(axis=1), ab.max(axis=1)
    key = lo * num_verts + hi
    order = np.argsort(key, kind="stable")
    ordered = key[order]  # sorted: each run of equal keys is one edge (np.unique's keys, first indices, counts)
    start = np.flatnonzero(np.r_[True, ordered[1:] != ordered[:-1]]) if len(ordered) else np.zeros(0, np.int64)
    count = np.diff(np.r_[start, len(ordered)])
    return ab[order], face[order], opposite[order], ordered[start], start, count, num_verts


def undirected_edges(faces: np.ndarray) -> np.ndarray:
    """Unique undirected edges (i < j), sorted, shape (E, 2) int64."""
    _, _, _, keys, _, _, num_verts = _edge_groups(faces)
    return np.stack([keys // max(num_verts, 1), keys % max(num_verts, 1)], axis=1).astype(np.int64)


def bidirectional_edges(edges: np.ndarray) -> np.ndarray:
    """Both directions of each undirected edge as `edge_index` (2, 2E), row 0 = sender."""
    edges = np.asarray(edges, dtype=np.int64)
    return np.concatenate([edges.T, edges[:, ::-1].T], axis=1)


def non_manifold_edges(faces: np.ndarray) -> np.ndarray:
    """Undirected edges shared by more than two faces, shape (K, 2) int64."""
    if len(faces) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    _, _, _, keys, _, count, num_verts = _edge_groups(faces)
    bad = keys[count > 2]
    return np.stack([bad // num_verts, bad % num_verts], axis=1).astype(np.int64)


def interior_hinges(faces: np.ndarray) -> np.ndarray:
    """The four vertices of each pair of triangles sharing an edge.

    Returns:
        hinges: shape (H, 4) int64, [v0, v1] the shared edge, v2 the opposite corner of the face in
        which v0→v1 is a half-edge, v3 the opposite corner of the other face. The signed dihedral
        angle (physics.bending) is zero for a flat hinge whatever the faces' winding.
    """
    ab, _, opposite, _, start, count, _ = _edge_groups(faces)
    first = start[count == 2]
    second = first + 1
    return np.stack([ab[first, 0], ab[first, 1], opposite[first], opposite[second]], axis=1)


def interior_hinge_faces(faces: np.ndarray) -> np.ndarray:
    """The two faces of each of `interior_hinges`' hinges, in its order, shape (H, 2) int64: first
    the face in which v0→v1 is a half-edge (the one holding v2), then the other (holding v3)."""
    _, face, _, _, start, count, _ = _edge_groups(faces)
    first = start[count == 2]
    return np.stack([face[first], face[first + 1]], axis=1)


def edge_neighbour_faces(faces: np.ndarray) -> np.ndarray:
    """For face f and local corner k, the other face across the edge opposite corner k (-1 if none).

    Returns shape (F, 3) int64. On a non-manifold edge one of the other faces is taken.
    """
    num_faces = faces.shape[0]
    a = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])  # edge opposite corner 0, 1, 2
    b = np.concatenate([faces[:, 2], faces[:, 0], faces[:, 1]])
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    half = np.arange(3 * num_faces)
    order = np.lexsort((half, hi, lo))
    key_lo, key_hi = lo[order], hi[order]
    same_next = np.zeros(3 * num_faces, dtype=bool)
    same_next[:-1] = (key_lo[1:] == key_lo[:-1]) & (key_hi[1:] == key_hi[:-1])
    partner = np.full(3 * num_faces, -1, dtype=np.int64)
    # Pair each half-edge with the next one of the same key, and the last of a run with the previous.
    nxt = np.flatnonzero(same_next)
    partner[order[nxt]] = order[nxt + 1]
    prv = nxt + 1
    unpaired = partner[order[prv]] < 0
    partner[order[prv[unpaired]]] = order[prv[unpaired] - 1]
    face_of = np.where(partner >= 0, partner % num_faces, -1)
    return face_of.reshape(3, num_faces).T.copy()


def face_rings(faces: np.ndarray, vertex_faces: np.ndarray) -> np.ndarray:
    """For each face, the other faces that share a vertex with it, each once, in increasing order,
    shape (F, W) int64 padded with F (W: the largest ring); vertex_faces: the faces around each
    vertex, (V, max degree) padded with F (`geometry.normals.vertex_face_table`)."""
    faces = np.asarray(faces, dtype=np.int64)
    num_faces = faces.shape[0]
    if num_faces == 0:
        return np.zeros((0, 0), dtype=np.int64)
    ring = np.sort(np.asarray(vertex_faces, dtype=np.int64)[faces].reshape(num_faces, -1), axis=1)
    repeat = np.zeros(ring.shape, dtype=bool)
    repeat[:, 1:] = ring[:, 1:] == ring[:, :-1]
    ring[repeat | (ring == np.arange(num_faces)[:, None])] = num_faces
    ring = np.sort(ring, axis=1)
    return ring[:, :int((ring < num_faces).sum(axis=1).max())]


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Half-edges a→b that belong to one face only, in that face's winding, shape (K, 2) int64."""
    ab, _, _, _, start, count, _ = _edge_groups(faces)
    return ab[start[count == 1]]


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Closed loops of boundary vertices, each in walking order (first vertex not repeated).

    A garment's loops are its openings (neck, hem, sleeve ends). A vertex where two loops touch
    (a bow-tie) is visited once per loop.
    """
    edges = boundary_edges(faces)
    outgoing: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        outgoing.setdefault(a, []).append(b)
    loops = []
    for start in sorted(outgoing):
        while outgoing.get(start):
            loop = [start]
            current = outgoing[start].pop()
            while current != start:
                loop.append(current)
                nexts = outgoing.get(current)
                if not nexts:  # an open chain: inconsistent winding at the boundary
                    break
                current = nexts.pop()
            loops.append(np.asarray(loop, dtype=np.int64))
    return loops


def connected_components(num_verts: int, faces: np.ndarray) -> np.ndarray:
    """Component label of each vertex through shared edges, shape (V,) int64 (isolated: own label)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as cc

    edges = undirected_edges(faces) if len(faces) else np.zeros((0, 2), dtype=np.int64)
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(num_verts, num_verts))
    _, labels = cc(graph, directed=False)
    return labels.astype(np.int64)


def vertex_adjacency(num_verts: int, edges: np.ndarray):
    """Symmetric 0/1 vertex adjacency of undirected `edges` (E, 2), a scipy CSR matrix (V, V)."""
    from scipy.sparse import coo_matrix

    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    rows = np.concatenate([edges[:, 0], edges[:, 1]])
    cols = np.concatenate([edges[:, 1], edges[:, 0]])
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_verts, num_verts)).tocsr()
    adjacency.data[:] = 1.0
    return adjacency


def drop_unused_vertices(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without the vertices no face uses (the others keep their order).

    Returns:
        verts: shape (V', 3); faces: shape (F, 3) int64, re-indexed.
    """
    used = np.unique(faces)
    remap = np.full(len(verts), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return verts[used], remap[faces]


def coarse_graphs(edges: np.ndarray, num_verts: int, levels: int) -> list[np.ndarray]:
    """A hierarchy of ever coarser graphs over subsets of a mesh's vertices (HOOD-style).

    Level l + 1 keeps a greedy maximal independent set of level l's nodes (so its nodes are about
    two level-l edges apart) and joins two kept nodes when their cells (the level-l nodes nearest
    to them by hops) touch. Each level roughly doubles the length of an edge, so L message-passing
    blocks over all levels reach about 2^levels times further than over the mesh edges alone.
    Deterministic: it depends on the topology and vertex order only.

    Args:
        edges: undirected mesh edges (E, 2) of vertex ids < num_verts (level 0).
        levels: number of coarse levels to build (0 gives an empty list).

    Returns:
        one array per coarse level 1 … levels of undirected edges (E_l, 2) in the mesh's vertex ids,
        i < j; a level of a single node per connected component has no edges (and ends the list).
    """
    return [level_edges for _, level_edges in _coarse_levels(edges, num_verts, levels)]


#: Levels a mesh's coarse hierarchy is built to at least, so that the coarse space's patches (two
#: levels) and the network's graph (four) share one build.
HIERARCHY_DEPTH = 4
#: The coarse hierarchies of the most recently seen edge arrays, by content and depth (a few tens of
#: kilobytes each: a training set's garments recur across its batches, and all of them are kept).
_HIERARCHIES = KeyedMemo(4096)


def _coarse_levels(edges: np.ndarray, num_verts: int, levels: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(nodes, edges) of each level of `coarse_graphs`, nodes as sorted mesh vertex ids, read-only
    (a level depends on the finer levels only: a shallower hierarchy is a deeper one's start)."""
    edges = np.ascontiguousarray(np.asarray(edges, dtype=np.int64).reshape(-1, 2))
    depth = max(levels, HIERARCHY_DEPTH)
    hierarchy = _HIERARCHIES.get((digest(edges), num_verts, depth),
                                 lambda: [_read_only(level) for level in _coarsen(edges, num_verts, depth)])
    return hierarchy[:levels]


def _coarsen(edges: np.ndarray, num_verts: int, levels: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """`_coarse_levels`, computed."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    nodes = np.unique(edges) if len(edges) else np.zeros(0, dtype=np.int64)
    out: list[tuple[np.ndarray, np.ndarray]] = []
    for _ in range(levels):
        if len(edges) == 0:
            break
        local = np.full(num_verts, -1, dtype=np.int64)
        local[nodes] = np.arange(len(nodes))
        a, b = local[edges[:, 0]], local[edges[:, 1]]
        n = len(nodes)
        adj = csr_matrix((np.ones(2 * len(a)), (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))
        indptr, indices = adj.indptr, adj.indices
        blocked = np.zeros(n, dtype=bool)
        centres = []
        for i in range(n):
            if not blocked[i]:
                centres.append(i)
                blocked[indices[indptr[i]:indptr[i + 1]]] = True
        centres = np.asarray(centres, dtype=np.int64)
        _, _, cell = dijkstra(adj, unweighted=True, indices=centres, min_only=True, return_predecessors=True)
        ca, cb = cell[a], cell[b]
        cross = ca != cb
        # the distinct pairs (low, high) in lexicographic order, as np.unique(axis=0) gives them,
        # by the unique of one integer key per pair (much cheaper than a unique over rows)
        low, high = np.minimum(ca[cross], cb[cross]).astype(np.int64), np.maximum(ca[cross], cb[cross])
        key = np.unique(low * n + high)  # int64: n² overflows int32 on a large mesh
        pairs = np.stack([key // n, key % n], axis=1)
        nodes = nodes[centres]
        edges = nodes[np.searchsorted(centres, pairs)] if len(pairs) else pairs
        edges = np.sort(edges, axis=1)
        out.append((nodes, edges))
    return out


def aggregates(edges: np.ndarray, num_verts: int, levels: int) -> np.ndarray:
    """Partition of a mesh's vertices into connected patches (the coarse space of a two-level solver).

    The seeds are the nodes of `coarse_graphs` level `levels` (about 2^levels edges apart; two
    levels give patches of 6–15 vertices); every vertex joins its nearest seed by hops through the
    mesh edges. A connected component without a seed (too small to keep one) and an isolated
    vertex each become one patch. Deterministic (topology and vertex order only).

    Returns:
        label (num_verts,) int64: the patch of each vertex, patches numbered 0 … P − 1.
    """
    from scipy.sparse.csgraph import connected_components as components
    from scipy.sparse.csgraph import dijkstra

    edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
    hierarchy = _coarse_levels(edges, num_verts, levels)
    seeds = hierarchy[-1][0] if hierarchy else np.unique(edges)
    adjacency = vertex_adjacency(num_verts, edges)
    label = np.full(num_verts, -1, dtype=np.int64)
    if len(seeds):
        _, _, cell = dijkstra(adjacency, unweighted=True, indices=seeds, min_only=True, return_predecessors=True)
        reached = cell >= 0
        label[reached] = np.searchsorted(seeds, cell[reached])
    count = len(seeds)
    if (label < 0).any():  # seedless components and isolated vertices: one patch each
        _, component = components(adjacency, directed=False)
        for c in np.unique(component[label < 0]):
            label[(component == c) & (label < 0)] = count
            count += 1
    return label


def smoothed_prolongation(edges: np.ndarray, num_verts: int, label: np.ndarray, passes: int):
    """Prolongation of a two-level solver: each patch's indicator over the vertices, averaged
    `passes` times over each vertex and its mesh neighbours (smoothed aggregation), rows then
    rescaled to sum to 1 (a rigid translation of all patches is one of the whole mesh).

    Returns:
        P: scipy CSR (num_verts, P) ≥ 0, each patch's column a smooth bump around it.
    """
    import scipy.sparse as sp

    count = int(label.max()) + 1 if len(label) else 0
    prolong = sp.csr_matrix((np.ones(num_verts), (np.arange(num_verts), label)), shape=(num_verts, count))
    if passes:
        average = vertex_adjacency(num_verts, edges) + sp.eye(num_verts, format="csr")
        average = sp.diags(1.0 / np.asarray(average.sum(1)).ravel()) @ average
        for _ in range(passes):
            prolong = average @ prolong
        prolong = sp.diags(1.0 / np.asarray(prolong.sum(1)).ravel()) @ prolong
    return prolong.tocsr()


#: Cuthill–McKee starts tried by `narrow_band_order`: the nodes farthest from the others.
BAND_ORDER_STARTS = 16


def narrow_band_order(rows: np.ndarray, cols: np.ndarray, num_nodes: int) -> np.ndarray:
    """A numbering of a symmetric sparsity pattern's nodes (new → old; entries (rows, cols))
    under which its entries lie close to the diagonal: the narrowest of reverse Cuthill–McKee
    orderings from scipy's start and from the `BAND_ORDER_STARTS` nodes of largest eccentricity,
    and the identity. Which start gives the narrowest band depends on the graph (on a garment's
    coarse patches the best start narrows scipy's band by about a fifth; a band factorisation
    costs the width squared)."""
    graph = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_nodes, num_nodes))
    graph = (graph + graph.T).tocsr()
    degree = np.diff(graph.indptr)
    # each node's neighbours in the order a Cuthill–McKee step queues them: by degree, then index
    neighbours = [sorted(graph.indices[graph.indptr[node]:graph.indptr[node + 1]].tolist(),
                         key=lambda n: (degree[n], n)) for node in range(num_nodes)]

    def width(order: np.ndarray) -> int:
        new = np.empty_like(order)
        new[order] = np.arange(num_nodes)
        return int(np.abs(new[rows] - new[cols]).max(initial=0))

    def reverse_cuthill_mckee_from(start: int) -> np.ndarray:
        order, seen = [], bytearray(num_nodes)
        for root in [start, *np.argsort(degree, kind="stable").tolist()]:  # every component
            if seen[root]:
                continue
            seen[root] = 1
            queue = collections.deque([root])
            while queue:
                node = queue.popleft()
                order.append(node)
                for n in neighbours[node]:
                    if not seen[n]:
                        seen[n] = 1
                        queue.append(n)
        return np.array(order[::-1], dtype=np.int64)

    candidates = [np.arange(num_nodes), reverse_cuthill_mckee(graph, symmetric_mode=True).astype(np.int64)]
    if num_nodes:
        hops = shortest_path(graph, unweighted=True)
        eccentricity = np.where(np.isinf(hops), -1.0, hops).max(axis=1)
        starts = np.lexsort((np.arange(num_nodes), -eccentricity))[:BAND_ORDER_STARTS]
        candidates += [reverse_cuthill_mckee_from(int(s)) for s in starts]
    return min(candidates, key=width)
