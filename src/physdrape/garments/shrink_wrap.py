"""Shrink-wrapping a garment patch onto the canonical body at a per-vertex offset (numpy).

Laplacian smoothing (bridges concavities) alternates with neighbour-averaged push-outs to the
offset, first against the smoothed body, then the real one with tangential relaxation; a local
untangling pass then removes self-intersections left in creases and puts every vertex at least
the collision margin off the body.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from physdrape.garments.body_fields import BodyFields, LegFields
from physdrape.garments.canonical import CanonicalBody
from physdrape.garments.numpy_geometry import vertex_normals
from physdrape.geometry.intersections import ray_hit_distances, self_intersecting_faces
from physdrape.geometry.topology import boundary_edges, undirected_edges, vertex_adjacency

__all__ = ["body_vertex_under", "shrink_wrap", "wrap_patch"]


def body_vertex_under(x: np.ndarray, f: BodyFields | LegFields, body: CanonicalBody) -> np.ndarray:
    """The body vertex nearest each point's closest body point (N,): where the per-vertex fields
    (arm-ness, leg-ness, normals) are read for a garment vertex."""
    _, closest, _ = f.query(x)
    return cKDTree(body.verts).query(closest)[1]


def wrap_patch(
    x: np.ndarray, faces: np.ndarray, offset: np.ndarray, f: BodyFields | LegFields, body: CanonicalBody, *,
    iterations: int, margin: float, smooth_weight: np.ndarray | None = None, clearance_floor=None,
) -> np.ndarray:
    """Move a patch cut from the (smoothed) body out to `offset` [m] per vertex and shrink-wrap it.

    The offset is capped at 0.4 of the free space in front of the body (the gap along the body's
    normal to the next body part: sheets over facing body parts, the arm and the torso under the
    armpit, the inner thighs, then cannot cross), kept at least margin + 1 mm, and raised to
    `clearance_floor(closest body points)` where one is given (`generate_garment`). The patch
    starts offset along its own normals (plus how deep the smoothed patch sank into the body): a
    smooth tube offset along its normals cannot fold, so tubes are nearly final there and the
    sweeps of `shrink_wrap` mostly shape the rest.
    """
    d, c, n = f.query(x)
    gap = ray_hit_distances(body.verts, body.faces, c + 1e-4 * n, n, max_t=1.0)
    offset = np.maximum(np.minimum(offset, 0.4 * gap), margin + 1e-3)
    if clearance_floor is not None:
        offset = np.maximum(offset, clearance_floor(c))
    sink = np.clip(-d, 0.0, None)
    x = x + vertex_normals(x, faces) * (offset + sink)[:, None]
    return shrink_wrap(x, faces, offset, f, iterations=iterations, margin=margin, smooth_weight=smooth_weight)


def shrink_wrap(
    x: np.ndarray, faces: np.ndarray, offset: np.ndarray, f: BodyFields | LegFields, *, iterations: int, margin: float,
    smooth_weight: np.ndarray | None = None,
) -> np.ndarray:
    """Offset surface that bridges concavities: smooth, then push out to ≥ `offset`.

    Args:
        x: garment patch positions [m], shape (V, 3).
        faces: triangles, shape (F, 3) int64.
        offset: target clearance from the body per vertex [m], shape (V,).
        f: the body's fields (the smoothed and the real body's distance queries).
        iterations: smoothing/push-out sweeps against the smoothed body (10 more follow against
            the real one).
        margin: collision margin [m]; every vertex ends at least margin + 0.5 mm off the body.
        smooth_weight: smoothing strength per vertex in [0, 1], shape (V,); None = 1 everywhere.

    Returns:
        the wrapped positions [m], shape (V, 3).
    """
    sweep, adj = _smoother(faces, len(x))
    deg = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    avg = sp.diags(1.0 / deg) @ adj
    # First against the smoothed (cleft-free) body, then a few sweeps against the real one.
    # Smoothing strength per vertex: full on the torso (bridges the armpit and other creases),
    # weak on the sleeves, whose tubes it would only shrink and pleat.
    a = np.ones((len(x), 1)) if smooth_weight is None else smooth_weight[:, None]
    for it in range(iterations + 10):
        query = f.smooth_query if it < iterations else f.query
        x = x + a * (sweep(x) - x)
        d, c, n = query(x)
        # Push-out displacement to the offset along the body normal, averaged over neighbours
        # before it is applied: across a crease the pushes of neighbouring vertices point at
        # each other and would fold the sheet; their average points out of it.
        disp = np.where((d < offset)[:, None], c + n * offset[:, None] - x, 0.0)
        for _ in range(2):
            disp = 0.5 * disp + 0.5 * (avg @ disp)
        x = x + a * disp
        if it >= iterations:
            x = _relax_tangential(x, faces, adj)
    return _untangle(x, faces, sweep, adj, f, margin=margin)


def _smoother(faces: np.ndarray, nv: int):
    """One smoothing sweep: Laplacian on interior vertices (bridges concavities), Taubin λ|μ
    along boundary loops (smooths the loop without shrinking it). Returns (sweep, adjacency)."""
    e = undirected_edges(faces)
    be = boundary_edges(faces)
    on_b = np.zeros(nv, bool)
    on_b[be.ravel()] = True

    def walk_of(edges, rows):
        w = vertex_adjacency(nv, edges)
        walk = sp.diags(1.0 / np.maximum(np.asarray(w.sum(1)).ravel(), 1)) @ w
        return (sp.diags(rows.astype(float)) @ walk + sp.diags((~rows).astype(float))).tocsr()

    w_in = walk_of(e, ~on_b)
    w_b = walk_of(be, on_b) if len(be) else sp.identity(nv, format="csr")

    def sweep(x: np.ndarray) -> np.ndarray:
        x = 0.5 * x + 0.5 * (w_in @ x)
        x = x + 0.5 * (w_b @ x - x)
        return x - 0.53 * (w_b @ x - x)

    return sweep, vertex_adjacency(nv, e)


def _relax_tangential(x: np.ndarray, faces: np.ndarray, adj, step: float = 0.5) -> np.ndarray:
    """Uniform Laplacian step with its normal component removed (evens out the triangles)."""
    nrm = vertex_normals(x, faces)
    delta = (adj @ x) / np.maximum(np.asarray(adj.sum(1)), 1) - x
    return x + step * (delta - (delta * nrm).sum(1, keepdims=True) * nrm)


def _untangle(x, faces, sweep, adj, f: BodyFields | LegFields, *, margin: float, rounds: int = 15) -> np.ndarray:
    """Remove self-intersections left in creases by local smoothing that keeps the margin.

    Each round smooths the vertices of intersecting faces and a few rings around them (the
    crease is bridged instead of pushed apart) and pushes out, along the sheet's own normal,
    only the vertices closer to the body than the margin.
    """
    clear = margin + 1e-3
    for _ in range(rounds):
        bad = self_intersecting_faces(x, faces)
        if len(bad) == 0:
            break
        sel = np.zeros(len(x), float)
        sel[faces[bad].ravel()] = 1.0
        for _ in range(4):
            sel = np.maximum(sel, (adj @ sel > 0).astype(float))
        m = sel > 0
        for k in range(8):
            xs = sweep(x)
            if k % 2:  # alternate with tangential relaxation, which unfolds small pleats
                xs = _relax_tangential(x, faces, adj)
            x[m] = xs[m]
            # Push along the sheet's own normal: in a cleft the body normals of neighbouring
            # vertices point at each other, the smoothed sheet's normal points out of it.
            d, _, _ = f.query(x[m])
            ng = vertex_normals(x, faces)[m]
            x[m] = x[m] + ng * np.clip(clear - d, 0.0, None)[:, None]
    d, c, n = f.query(x)
    low = d < clear - 5e-4
    x[low] = c[low] + n[low] * clear
    return x
