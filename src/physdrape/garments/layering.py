"""Which piece of a multi-piece garment lies over which, where they overlap on the canonical body.

Where two pieces come within `radius` of each other on the template (a top's hem over the
trousers' waistband, a jacket over a shirt), the vertex farther from the body is the outer one.
`layer_pairs` pairs every such vertex with its three nearest vertices of another piece, as
[outer, inner]; `physics.layers` keeps the pairs in that order during a drape. Each pair holds the
outer vertex above a plane through the inner one, so one partner leaves the inner sheet free to
bulge through between paired vertices (a tucked shirt bunching under trousers); three hold the
surface around it.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from physdrape.garments.numpy_geometry import BodyDistance

__all__ = ["LayerPairs", "layer_pairs"]


class LayerPairs(NamedTuple):
    """[outer, inner] vertex pairs (P, 2) int64 and how much farther from the body each outer
    vertex is than its inner one on the template [m] (P,): the separation the layers were
    authored with."""

    pairs: np.ndarray
    separation: np.ndarray


def layer_pairs(verts: np.ndarray, piece: np.ndarray, body_verts: np.ndarray, body_faces: np.ndarray, *,
                radius: float = 0.04, lift: float = 5e-4, neighbours: int = 3) -> LayerPairs:
    """[outer, inner] vertex pairs of different pieces that overlap on the template.

    Args:
        verts: template positions [m] (V, 3); piece: connected component of each vertex (V,).
        body_verts, body_faces: the canonical body the template is authored on.
        radius: largest distance between paired vertices [m] (pieces hanging loose over each
            other come into contact during a drape: measured on the MakeHuman suits, 4 cm covers
            them).
        lift: how much farther from the body the outer vertex must be [m] (pairs closer in body
            distance than this are side by side, not layered, and left out).
        neighbours: each vertex is paired with this many nearest vertices of other pieces (within
            `radius`).

    Returns:
        `LayerPairs`: the pairs as unique rows, sorted, and their separation.
    """
    x = np.asarray(verts, np.float64)
    piece = np.asarray(piece)
    none = LayerPairs(np.zeros((0, 2), np.int64), np.zeros(0))
    if len(x) == 0 or piece.max(initial=0) == 0:
        return none
    a, b = [], []
    for p in np.unique(piece):  # each vertex's nearest vertex of another piece
        own, other = np.flatnonzero(piece == p), np.flatnonzero(piece != p)
        dist, idx = cKDTree(x[other]).query(x[own], k=neighbours, distance_upper_bound=radius)
        dist, idx = dist.reshape(len(own), -1), idx.reshape(len(own), -1)
        found = np.isfinite(dist)
        a.append(np.broadcast_to(own[:, None], dist.shape)[found])
        b.append(other[idx[found]])
    a, b = np.concatenate(a), np.concatenate(b)
    if len(a) == 0:
        return none
    d = BodyDistance(body_verts, body_faces)(x)[0]
    outer = d[a] > d[b] + lift
    inner = d[b] > d[a] + lift
    pairs = np.concatenate([np.stack([a[outer], b[outer]], 1), np.stack([b[inner], a[inner]], 1)])
    pairs = np.unique(pairs.astype(np.int64), axis=0).reshape(-1, 2)
    return LayerPairs(pairs, d[pairs[:, 0]] - d[pairs[:, 1]])

