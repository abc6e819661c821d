"""Small mesh helpers shared by the garment modules (numpy/scipy only)."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def edges_with_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges, shape (E, 2) sorted per row, and how many faces use each, (E,)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.sort(e, axis=1)
    uniq, counts = np.unique(e, axis=0, return_counts=True)
    return uniq.astype(np.int64), counts


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Edges used by exactly one face, shape (B, 2) int64."""
    e, c = edges_with_counts(faces)
    return e[c == 1]


def boundary_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Boundary loops as ordered vertex index arrays (assumes an edge-manifold mesh)."""
    be = boundary_edges(faces)
    if len(be) == 0:
        return []
    nbrs: dict[int, list[int]] = {}
    for a, b in be:
        nbrs.setdefault(int(a), []).append(int(b))
        nbrs.setdefault(int(b), []).append(int(a))
    seen: set[int] = set()
    loops = []
    for start in sorted(nbrs):
        if start in seen:
            continue
        loop = [start]
        seen.add(start)
        prev, cur = -1, start
        while True:
            nxt = [n for n in nbrs[cur] if n != prev and n not in seen]
            if not nxt:
                break
            prev, cur = cur, nxt[0]
            loop.append(cur)
            seen.add(cur)
        loops.append(np.asarray(loop, np.int64))
    return loops


def connected_components(num_verts: int, faces: np.ndarray) -> tuple[int, np.ndarray]:
    """Face-connected components: (count, label per vertex (V,)); unused vertices get their own."""
    from scipy.sparse.csgraph import connected_components as cc

    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    a = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_verts, num_verts))
    return cc(a, directed=False)


def face_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted (unnormalised, = 2 * area * unit normal) face normals, shape (F, 3)."""
    v = verts[faces]
    return np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals, shape (V, 3)."""
    fn = face_normals(verts, faces)
    n = np.zeros_like(verts)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)


def face_areas(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas [m²], shape (F,)."""
    return 0.5 * np.linalg.norm(face_normals(verts, faces), axis=1)


def adjacency(num_verts: int, edges: np.ndarray) -> sp.csr_matrix:
    """Symmetric 0/1 vertex adjacency from edges (E, 2)."""
    a = sp.coo_matrix(
        (np.ones(2 * len(edges)), (np.r_[edges[:, 0], edges[:, 1]], np.r_[edges[:, 1], edges[:, 0]])),
        shape=(num_verts, num_verts),
    ).tocsr()
    a.data[:] = 1.0
    return a


def compact(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unreferenced vertices (keeping the order of the others)."""
    used = np.unique(faces)
    remap = -np.ones(len(verts), np.int64)
    remap[used] = np.arange(len(used))
    return verts[used], remap[faces]


def largest_component(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The face-connected component with the largest area."""
    _, lab = connected_components(len(verts), faces)
    flab = lab[faces[:, 0]]
    keep = flab == np.bincount(flab, weights=face_areas(verts, faces)).argmax()
    return compact(verts, faces[keep])
