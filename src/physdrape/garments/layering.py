"""Which piece of a multi-piece garment lies over which, where they overlap on the canonical body.

Where two pieces come within `radius` of each other on the template (a top's hem over the
trousers' waistband, a jacket over a shirt), the vertex farther from the body is the outer one.
`layer_pairs` pairs every such vertex with its nearest vertex of another piece, as [outer, inner];
`physics.layers` keeps the pairs in that order during a drape.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from physdrape.garments.numpy_geometry import BodyDistance

__all__ = ["layer_pairs"]


def layer_pairs(verts: np.ndarray, piece: np.ndarray, body_verts: np.ndarray, body_faces: np.ndarray, *,
                radius: float = 0.015, lift: float = 5e-4, neighbours: int = 12) -> np.ndarray:
    """[outer, inner] vertex pairs of different pieces that overlap on the template.

    Args:
        verts: template positions [m] (V, 3); piece: connected component of each vertex (V,).
        body_verts, body_faces: the canonical body the template is authored on.
        radius: largest distance between paired vertices [m].
        lift: how much farther from the body the outer vertex must be [m] (pairs closer in body
            distance than this are side by side, not layered, and left out).
        neighbours: nearest vertices searched per vertex.

    Returns:
        (P, 2) int64 [outer, inner], unique rows, sorted.
    """
    x = np.asarray(verts, np.float64)
    piece = np.asarray(piece)
    if len(x) == 0 or piece.max(initial=0) == 0:
        return np.zeros((0, 2), np.int64)
    dist, idx = cKDTree(x).query(x, k=min(neighbours, len(x)), distance_upper_bound=radius)
    found = np.isfinite(dist) & (idx < len(x))
    idx = np.where(found, idx, 0)
    other = found & (piece[idx] != piece[:, None])
    # nearest vertex of another piece, per vertex
    first = np.argmax(other, axis=1)
    has = other.any(axis=1)
    a = np.flatnonzero(has)
    b = idx[a, first[a]]
    if len(a) == 0:
        return np.zeros((0, 2), np.int64)
    d = BodyDistance(body_verts, body_faces)(x)[0]
    outer_a = d[a] > d[b] + lift
    outer_b = d[b] > d[a] + lift
    pairs = np.concatenate([np.stack([a[outer_a], b[outer_a]], 1), np.stack([b[outer_b], a[outer_b]], 1)])
    return np.unique(pairs.astype(np.int64), axis=0).reshape(-1, 2)
