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
import torch

from physdrape.garments.numpy_geometry import BodyDistance
from physdrape.geometry.neighbours import nearest_within
from physdrape.physics.layers import FOLLOW_NEIGHBOURS, FOLLOW_RADIUS

__all__ = ["LayerPairs", "layer_pairs"]


class LayerPairs(NamedTuple):
    """[outer, inner] vertex pairs (P, 2) int64 and how much farther from the body each outer
    vertex is than its inner one on the template [m] (P,): the separation the layers were
    authored with; the pieces' order (K, K) bool (True where piece a lies over piece b by their
    consensus) and each vertex's distance from the body on the template [m] (V,), from which the
    pairs that `physics.layers.follow_pairs` adds as the pieces slide take their gaps."""

    pairs: np.ndarray
    separation: np.ndarray
    over: np.ndarray
    depth: np.ndarray


def layer_pairs(verts: np.ndarray, piece: np.ndarray, body_verts: np.ndarray, body_faces: np.ndarray, *,
                radius: float = FOLLOW_RADIUS, lift: float = 5e-4, neighbours: int = FOLLOW_NEIGHBOURS,
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
    pieces = int(piece.max(initial=0)) + 1
    none = LayerPairs(np.zeros((0, 2), np.int64), np.zeros(0), np.zeros((pieces, pieces), bool), np.zeros(len(x)))
    if len(x) == 0 or pieces == 1:
        return none
    a, b = [], []
    points = torch.from_numpy(x)
    for p in np.unique(piece):  # each vertex's nearest vertices of other pieces
        own, other = np.flatnonzero(piece == p), np.flatnonzero(piece != p)
        i, j = (t.numpy() for t in nearest_within(points[own], points[other], k=neighbours, radius=radius))
        a.append(own[i])
        b.append(other[j])
    a, b = np.concatenate(a), np.concatenate(b)
    if len(a) == 0:
        return none
    d = BodyDistance(body_verts, body_faces)(x)[0]
    outer = d[a] > d[b] + lift
    inner = d[b] > d[a] + lift
    over = _piece_order(piece[a], piece[b], outer, inner, consensus, pieces)
    a_over, b_over = over[piece[a], piece[b]], over[piece[b], piece[a]]
    ordered = a_over | b_over
    outer = np.where(ordered, a_over, outer)
    inner = np.where(ordered, b_over, inner)
    pairs = np.concatenate([np.stack([a[outer], b[outer]], 1), np.stack([b[inner], a[inner]], 1)])
    pairs = np.unique(pairs.astype(np.int64), axis=0).reshape(-1, 2)
    return LayerPairs(pairs, d[pairs[:, 0]] - d[pairs[:, 1]], over, d)


def _piece_order(pa: np.ndarray, pb: np.ndarray, outer: np.ndarray, inner: np.ndarray, consensus: float,
                 pieces: int) -> np.ndarray:
    """The pieces' order (pieces, pieces) bool: True at (p, q) where at least `consensus` of the
    clearly layered candidate pairs of pieces p and q (pa, pb: each pair's pieces; `outer`: a
    clearly outside b, `inner`: inside) put p outside."""
    votes = np.zeros((pieces, pieces))
    np.add.at(votes, (pa, pb), outer)
    np.add.at(votes, (pb, pa), inner)
    clear = votes + votes.T
    return (clear > 0) & (votes >= consensus * clear)
