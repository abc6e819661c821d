"""Local untangling of garment self-intersections next to a body (layered MakeHuman suits).

MakeHuman suits are a top and trousers (sometimes more pieces) authored as separate sheets that
overlap at the waist, and tight clothes refit onto Anny cross themselves in creases (crotch,
armpits). `untangle_garment` resolves such crossings locally, keeping the rest of the garment
where it is:

1. layering: for every crossing face pair, the face farther from the body is the outer one; it is
   moved out along the body normal until it clears the inner face by `gap`, the inner one is moved
   in by up to half of that (never closer to the body than the margin); each move is spread over
   a few rings of neighbours so the sheet does not crease;
2. smoothing fallback (rounds with crossings left, as in `shrink_wrap`): vertices around the
   remaining crossings alternate Laplacian and tangential relaxation steps, then are pushed back
   out to the margin along the sheet normal;
3. every vertex closer to the body than the margin is put at margin + 0.5 mm (first, and after
   every round).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physdrape.garments.numpy_geometry import BodyDistance, vertex_normals
from physdrape.geometry.intersections import self_intersecting_pairs
from physdrape.geometry.topology import undirected_edges, vertex_adjacency

__all__ = ["UntangleInfo", "untangle_garment"]


@dataclass
class UntangleInfo:
    """What `untangle_garment` did: crossing faces before/after, rounds run, moved vertices, and
    its settings (the gap [m], the spread rings)."""

    faces_before: int
    faces_after: int
    rounds: int
    moved_verts: int
    gap: float = 0.0
    spread_rings: int = 0

    def as_dict(self) -> dict:
        return {"self_intersecting_faces_before": self.faces_before,
                "self_intersecting_faces_after": self.faces_after,
                "rounds": self.rounds, "moved_verts": self.moved_verts, "gap_m": self.gap,
                "spread_rings": self.spread_rings}


def _adjacency(num_verts: int, faces: np.ndarray):
    adj = vertex_adjacency(num_verts, undirected_edges(np.asarray(faces, np.int64)))
    deg = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    return adj, deg


def _push_out(x: np.ndarray, q, margin: float) -> np.ndarray:
    d, c, n = q(x)
    low = d < margin
    x = x.copy()
    x[low] = c[low] + n[low] * (margin + 5e-4)
    return x


def untangle_garment(
    verts: np.ndarray,
    faces: np.ndarray,
    body_verts: np.ndarray,
    body_faces: np.ndarray,
    *,
    margin: float = 2e-3,
    gap: float = 2e-3,
    rounds: int = 40,
    spread_rings: int = 3,
) -> tuple[np.ndarray, UntangleInfo]:
    """Remove self-intersections of a garment lying on a body by local moves.

    Args:
        verts: garment positions [m] (V, 3); faces: triangles (F, 3) int.
        body_verts, body_faces: the closed body [m].
        margin: clearance kept from the body [m].
        gap: distance the outer of two crossing faces is put beyond the inner one [m].
        rounds: at most this many detect-and-move rounds.
        spread_rings: rings of neighbours over which a move is faded out.

    Returns:
        (new positions [m] (V, 3) float64, `UntangleInfo`). Vertices closer to the body than
        `margin` are first put at margin + 0.5 mm (so are those that end a round there); the
        others move only near crossings.
    """
    faces = np.asarray(faces, np.int64)
    q = BodyDistance(np.asarray(body_verts, np.float64), np.asarray(body_faces, np.int64))
    x = np.array(verts, np.float64)
    adj, deg = _adjacency(len(x), faces)
    start = x.copy()
    x = _push_out(x, q, margin)
    pairs = self_intersecting_pairs(x, faces)
    before = len(np.unique(pairs))
    done = 0
    for r in range(rounds):
        if len(pairs) == 0:
            break
        done = r + 1
        d, _, n = q(x)
        fd = d[faces].mean(1)
        a, b = pairs[:, 0], pairs[:, 1]
        swap = fd[a] < fd[b]
        outer, inner = np.where(swap, b, a), np.where(swap, a, b)
        fo, fi = faces[outer], faces[inner]  # (K, 3)
        need = d[fi].max(1) + gap - d[fo].min(1)  # how far the outer face must go out
        need = np.maximum(need, 5e-4)
        # the inner face goes in by up to half of it, never below the margin (+0.5 mm)
        room = np.clip(d[fi].min(1) - (margin + 5e-4), 0.0, None)
        down = np.minimum(0.5 * need, room)
        up = need - down
        amount = np.zeros(len(x))
        count = np.zeros(len(x))
        np.add.at(amount, fo.ravel(), np.repeat(up, 3))
        np.add.at(count, fo.ravel(), 1.0)
        np.add.at(amount, fi.ravel(), -np.repeat(down, 3))
        np.add.at(count, fi.ravel(), 1.0)
        hit = count > 0
        amount[hit] /= count[hit]
        # fade the move out over a few rings (neighbours follow with 1/2, 1/4, ...)
        field = amount.copy()
        fixed = hit.copy()
        for _ in range(spread_rings):
            fixed_f = fixed.astype(float)
            nb = (adj @ fixed_f > 0) & ~fixed
            field[nb] = 0.5 * (adj @ field)[nb] / (adj @ fixed_f)[nb]
            fixed |= nb
        x = x + field[:, None] * n
        if r % 3 == 2:  # a few rounds of plain layering that did not converge: smooth the knots
            pairs = self_intersecting_pairs(x, faces)
            if len(pairs):
                x = _smooth_region(x, faces, adj, deg, np.unique(pairs), q, margin, vertex_normals)
        x = _push_out(x, q, margin)
        pairs = self_intersecting_pairs(x, faces)
    moved = int((np.linalg.norm(x - start, axis=1) > 1e-9).sum())
    return x, UntangleInfo(faces_before=before, faces_after=len(np.unique(pairs)), rounds=done,
                           moved_verts=moved, gap=gap, spread_rings=spread_rings)


def _smooth_region(x, faces, adj, deg, bad_faces, q, margin, vertex_normals, *, rings: int = 2,
                   steps: int = 4) -> np.ndarray:
    """Laplacian/tangential smoothing of the vertices around `bad_faces`, then a push back out to
    the margin along the sheet normal (bridges a crease instead of pushing it apart)."""
    sel = np.zeros(len(x))
    sel[faces[bad_faces].ravel()] = 1.0
    for _ in range(rings):
        sel = np.maximum(sel, (adj @ sel > 0).astype(float))
    m = sel > 0
    x = x.copy()
    for k in range(steps):
        delta = (adj @ x) / deg[:, None] - x
        if k % 2:
            nrm = vertex_normals(x, faces)
            delta = delta - (delta * nrm).sum(1, keepdims=True) * nrm
        x[m] = x[m] + 0.5 * delta[m]
        d, _, _ = q(x[m])
        ng = vertex_normals(x, faces)[m]
        x[m] = x[m] + ng * np.clip(margin + 1e-3 - d, 0.0, None)[:, None]
    return x
