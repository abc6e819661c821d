"""Where a garment's panels overlap on the canonical body: button fronts, wrap fronts, a jacket's
edge on the shirt under it.

A template authored closed has its front panels lying on each other: vertices of two panels a few
millimetres apart that are far apart along the mesh (or on different pieces). Nothing in the
physics of a free sheet keeps them together; a closure ties them (`physdrape.physics.stitches`).

`panel_overlaps` finds those vertex pairs on the template: pairs closer than `radius` in space
whose vertices are more than `min_hops` mesh edges apart (or on different pieces), at least one of
them on an opening's edge (a panel's edge lying on another panel, not two whole layers sliding on
each other), both outside `exclude` (e.g. the trousers, whose overlap with a top is layering).
Each vertex is kept in at most one pair, its nearest partner.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from physdrape.geometry.topology import boundary_edges, undirected_edges

__all__ = ["panel_overlaps"]

#: Distances held at once by the one-panel test's searches (rows × vertices, float64: 80 MB).
_HOP_ROWS = 10_000_000


def panel_overlaps(verts: np.ndarray, faces: np.ndarray, piece: np.ndarray, *, radius: float = 12e-3,
                   min_hops: int = 6, exclude: np.ndarray | None = None) -> np.ndarray:
    """Vertex pairs where a template's panels overlap (module docstring).

    Args:
        verts: template positions [m] (V, 3); faces: (F, 3) int; piece: connected component of
            each vertex (V,) (`garments.pieces.garment_parts`).
        radius: largest distance between overlapping vertices [m].
        min_hops: vertices of one piece closer than this many mesh edges are one panel.
        exclude: vertices never paired (V,) bool, or None.

    Returns:
        pairs (K, 2) int64, i < j per row, sorted by i.
    """
    x = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    num_verts = len(x)
    pairs = cKDTree(x).query_pairs(radius, output_type="ndarray").astype(np.int64)
    if len(pairs) == 0:
        return np.zeros((0, 2), np.int64)
    on_edge = np.zeros(num_verts, bool)
    on_edge[boundary_edges(f).reshape(-1)] = True
    keep = on_edge[pairs[:, 0]] | on_edge[pairs[:, 1]]
    if exclude is not None:
        keep &= ~(exclude[pairs[:, 0]] | exclude[pairs[:, 1]])
    pairs = pairs[keep]
    same = piece[pairs[:, 0]] == piece[pairs[:, 1]]
    if same.any():
        # one panel: at most min_hops mesh edges apart (a search of min_hops from each pair's first vertex)
        e = undirected_edges(f)
        adj = sp.coo_matrix((np.ones(2 * len(e)), (np.r_[e[:, 0], e[:, 1]], np.r_[e[:, 1], e[:, 0]])),
                            shape=(num_verts, num_verts)).tocsr()
        first, second = pairs[same, 0], pairs[same, 1]
        near = np.zeros(len(first), bool)
        sources = np.unique(first)
        chunk = max(1, _HOP_ROWS // num_verts)  # the searches' (sources, V) distances, a bounded block at a time
        for start in range(0, len(sources), chunk):
            some = sources[start:start + chunk]
            hops = dijkstra(adj, unweighted=True, indices=some, limit=min_hops)
            mine = (first >= some[0]) & (first <= some[-1])
            near[mine] = hops[np.searchsorted(some, first[mine]), second[mine]] <= min_hops
        far = np.ones(len(pairs), bool)
        far[np.flatnonzero(same)[near]] = False
        pairs = pairs[far]
    if len(pairs) == 0:
        return np.zeros((0, 2), np.int64)
    # each vertex in at most one pair: nearest pairs first
    order = np.argsort(np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1), kind="stable")
    used = np.zeros(num_verts, bool)
    out = []
    for i, j in pairs[order]:
        if not used[i] and not used[j]:
            used[i] = used[j] = True
            out.append((min(i, j), max(i, j)))
    out = np.asarray(out, np.int64).reshape(-1, 2)
    return out[np.argsort(out[:, 0], kind="stable")]
