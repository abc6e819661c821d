"""Which piece of a multi-piece garment lies over which, where they overlap on the canonical body.

Where two pieces come within `radius` of each other on the template (a top's hem over the
trousers' waistband, a jacket over a shirt), `layer_pairs` pairs every such vertex with its three
nearest vertices of another piece, as [outer, inner]; `physics.layers` keeps the pairs in that
order during a drape. Each pair holds the outer vertex above a plane through the inner one, so one
partner leaves the inner sheet free to bulge through between paired vertices (a tucked shirt
bunching under trousers); three hold the surface around it.

Which vertex is outer is decided per pair of pieces where the pieces agree: when nearly all
(`consensus`) of their clearly layered vertex pairs (one vertex farther from the body than the
other by more than `lift`) put the same piece outside, every near pair of the two pieces takes that
order, including the pairs that lie side by side on the template (a top's hem level with the
waistband) or a little the other way round: those are where the pieces cross during a drape if
left free. Pieces that interleave (a shirt tucked in at the front and out at the back) keep the
per-vertex order, and their side-by-side pairs stay unpaired.
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
                radius: float = 0.04, lift: float = 5e-4, neighbours: int = 3,
                consensus: float = 0.9) -> LayerPairs:
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
        consensus: the share of two pieces' clearly layered pairs that must put the same piece
            outside for all their near pairs to take that order (measured on the MakeHuman suits:
            95-100 % agree where one piece lies over another).

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
    a_over = _piece_order(piece[a], piece[b], outer, inner, consensus)
    outer = np.where(np.isnan(a_over), outer, a_over == 1.0)
    inner = np.where(np.isnan(a_over), inner, a_over == 0.0)
    pairs = np.concatenate([np.stack([a[outer], b[outer]], 1), np.stack([b[inner], a[inner]], 1)])
    pairs = np.unique(pairs.astype(np.int64), axis=0).reshape(-1, 2)
    return LayerPairs(pairs, d[pairs[:, 0]] - d[pairs[:, 1]])



def _piece_order(pa: np.ndarray, pb: np.ndarray, outer: np.ndarray, inner: np.ndarray, consensus: float) -> np.ndarray:
    """Per candidate pair (pieces pa, pb; a clearly outside b: `outer`, inside: `inner`): 1 where
    a's piece lies over b's by the two pieces' consensus, 0 where under it, NaN where the pieces
    do not agree (or have no clearly layered pair)."""
    lo, hi = np.minimum(pa, pb), np.maximum(pa, pb)
    key = lo * (max(int(pa.max()), int(pb.max())) + 1) + hi
    lo_out = np.where(pa == lo, outer, inner)  # the pair says lo's piece is outside
    hi_out = np.where(pa == lo, inner, outer)
    keys, which = np.unique(key, return_inverse=True)
    votes_lo = np.bincount(which, lo_out, len(keys))
    votes_hi = np.bincount(which, hi_out, len(keys))
    clear = np.maximum(votes_lo + votes_hi, 1)
    lo_over = np.full(len(keys), np.nan)
    lo_over[votes_lo >= consensus * clear] = 1.0
    lo_over[votes_hi >= consensus * clear] = 0.0
    lo_over[votes_lo + votes_hi == 0] = np.nan
    order = lo_over[which]
    return np.where(pa == lo, order, 1.0 - order)
