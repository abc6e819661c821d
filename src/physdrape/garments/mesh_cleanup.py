"""Remove the short edges and slivers that a remesher leaves next to fixed boundary polylines.

The remesher keeps each boundary loop on its input polyline, and a polyline cut from the body
mesh by a contour has irregular spacing: along the openings a garment gets edges far shorter
than the median and triangles of a tiny fraction of the median area. Such elements carry almost
no mass and stiffen the explicit physics (a 0.3 mm edge whose ends move 5 mm apart is
stretched 17x). Two passes fix them without changing the topology class:

1. **Edge collapse** of edges shorter than ``min_edge`` (shortest first, an independent set per
   sweep), only where the link condition holds (the mesh stays a manifold with the same loops),
   no triangle flips or degenerates, and an interior edge joining two boundary vertices is never
   collapsed (it would pinch the surface). A boundary vertex keeps its place; two boundary (or
   two interior) vertices merge at their midpoint.
2. **Delaunay edge flips** of interior edges whose opposite angles sum to more than pi, where the
   two triangles are nearly coplanar (so the surface keeps its shape): flat "cap" triangles with a
   vertex close to the opposite edge become well shaped.
"""

from __future__ import annotations

import numpy as np

from physdrape.geometry.topology import (
    boundary_edges,
    boundary_loops,
    drop_unused_vertices,
    interior_hinge_faces,
    interior_hinges,
    undirected_edges,
)

__all__ = ["collapse_short_edges", "flip_to_delaunay", "remove_flat_ears", "repair_moved_mesh"]


def _incidence(rows: np.ndarray, items: np.ndarray, num_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """`items` grouped by `rows` (compressed rows): (start (num_rows + 1,), items in row order), so
    that row r's items are items[start[r]:start[r + 1]]."""
    order = np.argsort(rows, kind="stable")
    return np.searchsorted(rows[order], np.arange(num_rows + 1)), items[order]


def _row(incidence: tuple[np.ndarray, np.ndarray], r: int) -> set[int]:
    start, items = incidence
    return set(items[start[r]:start[r + 1]].tolist())


def _normal(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    return np.cross(b - a, c - a)


def collapse_short_edges(verts: np.ndarray, faces: np.ndarray, min_edge: float, *,
                         sweeps: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Collapse the edges shorter than `min_edge` [m] (see the module docstring).

    Returns:
        (verts, faces) without the collapsed vertices (the others keep their order).
    """
    v = np.asarray(verts, np.float64).copy()
    f = np.asarray(faces, np.int64).copy()
    for _ in range(sweeps):
        e = undirected_edges(f)
        length = np.linalg.norm(v[e[:, 0]] - v[e[:, 1]], axis=1)
        candidates = np.nonzero(length < min_edge)[0]
        if not len(candidates):
            break
        be = boundary_edges(f)
        on_boundary = np.zeros(len(v), bool)
        on_boundary[be.ravel()] = True
        boundary_set = {(min(a, b), max(a, b)) for a, b in be.tolist()}
        # each vertex's faces and neighbours, read only for the candidates' ends
        vf = _incidence(f.ravel(), np.repeat(np.arange(len(f)), 3), len(v))
        neighbours = _incidence(e.T.ravel(), e[:, ::-1].T.ravel(), len(v))
        locked = np.zeros(len(v), bool)
        remap = np.arange(len(v))
        done = 0
        for k in candidates[np.argsort(length[candidates], kind="stable")].tolist():
            a, b = (int(x) for x in e[k])
            if locked[a] or locked[b]:
                continue
            if on_boundary[a] and on_boundary[b] and (a, b) not in boundary_set:
                continue  # would pinch the surface
            if on_boundary[b] and not on_boundary[a]:
                a, b = b, a  # keep the boundary vertex
            target = v[a] if on_boundary[a] != on_boundary[b] else 0.5 * (v[a] + v[b])
            faces_a, faces_b = _row(vf, a), _row(vf, b)
            shared = faces_a & faces_b
            opposite = {x for s in shared for x in f[s].tolist()} - {a, b}
            if _row(neighbours, a) & _row(neighbours, b) != opposite:
                continue  # link condition fails: the collapse would change the topology
            ok = True
            for s in (faces_a | faces_b) - shared:
                tri = f[s]
                before = _normal(*v[tri])
                moved = v[tri].copy()
                moved[(tri == a) | (tri == b)] = target
                after = _normal(*moved)
                norm_b, norm_a = np.linalg.norm(before), np.linalg.norm(after)
                if norm_a < 1e-3 * norm_b or np.dot(before, after) < 0.5 * norm_b * norm_a:
                    ok = False
                    break
            if not ok:
                continue
            v[a] = target
            remap[b] = a
            for x in (a, b):
                locked[x] = True
                locked[neighbours[1][neighbours[0][x]:neighbours[0][x + 1]]] = True
            done += 1
        if not done:
            break
        f = remap[f]
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 2] != f[:, 0])]
        v, f = drop_unused_vertices(v, f)
    return v, f


def remove_flat_ears(verts: np.ndarray, faces: np.ndarray, *, max_angle_deg: float = 140.0,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Delete boundary "ears": a face whose corner b lies on the boundary, belongs to no other
    face and has an angle above `max_angle_deg` (b almost on the edge joining its neighbours).
    The neighbours' edge becomes the boundary; the loop stays a loop, one vertex shorter.

    Returns:
        (verts, faces) without the ear vertices (the others keep their order).
    """
    v = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    degree = np.bincount(f.ravel(), minlength=len(v))
    loops_len = {}
    for loop in boundary_loops(f):
        for x in loop.tolist():
            loops_len[x] = len(loop)
    drop = np.zeros(len(f), bool)
    used = np.zeros(len(v), bool)
    limit = np.radians(max_angle_deg)
    for k, tri in enumerate(f.tolist()):
        for i in range(3):
            b, a, c = tri[i], tri[(i + 1) % 3], tri[(i + 2) % 3]
            if degree[b] != 1 or loops_len.get(b, 0) <= 4 or used[[a, b, c]].any():
                continue
            if _angle_at(v[b], v[a], v[c]) > limit:
                drop[k] = True
                used[[a, b, c]] = True
                break
    if not drop.any():
        return v, f
    return drop_unused_vertices(v, f[~drop])


def _angle_at(p: np.ndarray, q: np.ndarray, r: np.ndarray) -> float:
    """Interior angle at p of the triangle (p, q, r)."""
    u, w = q - p, r - p
    return float(np.arctan2(np.linalg.norm(np.cross(u, w)), np.dot(u, w)))


def flip_to_delaunay(verts: np.ndarray, faces: np.ndarray, *, max_dihedral_deg: float = 20.0,
                     sweeps: int = 5, fold_area_ratio: float = 0.0) -> np.ndarray:
    """Flip interior edges whose opposite angles sum to more than pi (see the module docstring).

    fold_area_ratio: also flip where a sliver is folded over its neighbour (their normals
    opposite within `max_dihedral_deg`, the sliver under this fraction of the neighbour's area):
    its far corner lies just across the shared edge, so the flip unfolds it; such a triangle,
    flat in the rest shape, would be stretched without bound by any move of that corner.
    0: coplanar pairs only.

    Returns:
        faces with the same vertices, winding kept.
    """
    v = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64).copy()
    cos_limit = np.cos(np.radians(max_dihedral_deg))

    def angle(p, q, r):  # at p, vectorised
        u, w = q - p, r - p
        return np.arctan2(np.linalg.norm(np.cross(u, w), axis=-1), (u * w).sum(-1))

    for _ in range(sweeps):
        h = interior_hinges(f)
        a, b, c, d = (v[h[:, i]] for i in range(4))
        n_s, n_t = np.cross(b - a, c - a), np.cross(a - b, d - b)
        norm_s, norm_t = np.linalg.norm(n_s, axis=-1), np.linalg.norm(n_t, axis=-1)
        cosine = (n_s * n_t).sum(-1)
        coplanar = cosine >= cos_limit * norm_s * norm_t
        folded = (cosine <= -cos_limit * norm_s * norm_t) & (np.minimum(norm_s, norm_t)
                                                              < fold_area_ratio * np.maximum(norm_s, norm_t))
        excess = angle(c, a, b) + angle(d, a, b) - np.pi
        candidates = np.nonzero((excess > 1e-9) & (coplanar | folded))[0]
        if not len(candidates):
            break
        faces_of = interior_hinge_faces(f)
        edges = undirected_edges(f)
        keys = edges[:, 0] * len(v) + edges[:, 1]  # sorted, as the edges are
        added: set[tuple[int, int]] = set()  # the edges this sweep's flips made

        def has_edge(i: int, j: int) -> bool:
            lo, hi = min(i, j), max(i, j)
            at = int(np.searchsorted(keys, lo * len(v) + hi))
            return (at < len(keys) and int(keys[at]) == lo * len(v) + hi) or (lo, hi) in added

        touched = np.zeros(len(f), bool)
        flipped = 0
        for k in candidates[np.argsort(-excess[candidates], kind="stable")].tolist():
            x, y, p, q = (int(i) for i in h[k])  # face s holds the half-edge x -> y, third corner p
            s, t = (int(i) for i in faces_of[k])
            if touched[s] or touched[t] or has_edge(p, q):
                continue
            new_s, new_t = np.array([p, x, q]), np.array([p, q, y])
            ref = _normal(*v[f[s]]) + _normal(*v[f[t]])
            if min(np.dot(_normal(*v[new_s]), ref), np.dot(_normal(*v[new_t]), ref)) <= 0:
                continue
            f[s], f[t] = new_s, new_t
            touched[[s, t]] = True
            added.add((min(p, q), max(p, q)))
            flipped += 1
        if not flipped:
            break
    return f


def repair_moved_mesh(verts: np.ndarray, faces: np.ndarray, *, min_edge: float,
                      fold_area_ratio: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Clean a finished mesh after its vertices were moved one by one (pushed out of a body,
    layers pulled apart): such moves squeeze edges and fold slivers over their neighbours, and
    the garment's rest shape must not keep them. Collapses the edges shorter than `min_edge` [m]
    and flips slivers, folded ones included (`flip_to_delaunay`'s `fold_area_ratio`).

    Returns:
        (verts, faces) without the collapsed vertices (the others keep their order).
    """
    v, f = collapse_short_edges(verts, faces, min_edge)
    return v, flip_to_delaunay(v, f, fold_area_ratio=fold_area_ratio)
