"""Isotropic remeshing of garment templates to a target edge length, boundary loops kept.

Uses gpytoolbox's Botsch-Kobbelt remesher (split / collapse / flip / tangential relaxation,
reprojection onto the input). Boundary edges are passed as feature edges: they are split and
collapsed only along the boundary and their vertices stay on the input's boundary polylines, so
every open loop (neck, hem, sleeve ends) survives with its shape. Because those polylines keep
their irregular spacing, the result is then cleaned (`physdrape.garments.mesh_cleanup`: short
edges collapsed, flat boundary ears removed, slivers flipped) and remeshed once more.
"""

from __future__ import annotations

import warnings

import numpy as np

from physdrape.garments.mesh_cleanup import collapse_short_edges, flip_to_delaunay, remove_flat_ears
from physdrape.geometry.topology import (
    boundary_edges,
    connected_components,
    drop_unused_vertices,
    undirected_edges,
)

__all__ = ["remesh", "mean_edge_length"]

#: Edges shorter than this fraction of the target are collapsed after remeshing.
SHORT_EDGE_RATIO = 0.35


def mean_edge_length(verts: np.ndarray, faces: np.ndarray) -> float:
    """Mean length of the unique edges [m]."""
    e = undirected_edges(faces)
    return float(np.linalg.norm(verts[e[:, 0]] - verts[e[:, 1]], axis=1).mean())


def remesh(
    verts: np.ndarray,
    faces: np.ndarray,
    *,
    target_edge: float = 0.015,
    iterations: int = 10,
) -> tuple[np.ndarray, np.ndarray]:
    """Remesh a triangle mesh to near-uniform edges of `target_edge`, keeping boundary loops.

    Args:
        verts: vertex positions [m], shape (V, 3).
        faces: triangles, shape (F, 3) int.
        target_edge: desired edge length [m].
        iterations: remeshing sweeps (10 is plenty for garments).

    Returns:
        verts: new vertex positions [m], shape (V', 3) float64.
        faces: new triangles, shape (F', 3) int64. Deterministic for a given input.
    """
    try:
        import gpytoolbox
    except ImportError as err:  # pragma: no cover
        raise ImportError(
            "remeshing needs gpytoolbox: pip install gpytoolbox (CPU wheels on PyPI)"
        ) from err
    if target_edge <= 0:
        raise ValueError(f"target_edge must be > 0 [m], got {target_edge}")
    v, f = drop_unused_vertices(np.asarray(verts, np.float64), np.asarray(faces, np.int64))
    lab = connected_components(len(v), f)
    flab = lab[f[:, 0]]
    out_v, out_f, n = [], [], 0
    for comp in np.unique(flab):  # one component at a time (the C++ remesher is per surface)
        cv, cf = drop_unused_vertices(v, f[flab == comp])
        try:
            rv, rf = _remesh_component(gpytoolbox, cv, cf, target_edge, iterations)
        except (MemoryError, RuntimeError, ValueError) as err:
            warnings.warn(f"remeshing a component of {len(cv)} vertices failed ({err!r}); kept as is")
            rv, rf = cv, cf
        out_v.append(rv)
        out_f.append(rf + n)
        n += len(rv)
    return np.concatenate(out_v), np.concatenate(out_f)


def _inconsistent_winding(f: np.ndarray) -> int:
    """Directed edges used twice (two neighbouring faces with opposite orientations)."""
    he = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    _, cnt = np.unique(he, axis=0, return_counts=True)
    return int((cnt > 1).sum())


def _remesh_component(gpytoolbox, v, f, target_edge, iterations):
    if _inconsistent_winding(f):
        # Some assets (a MakeHuman collar) mix face orientations; the remesher needs one.
        import trimesh

        m = trimesh.Trimesh(v, f, process=False)
        trimesh.repair.fix_winding(m)
        f = np.asarray(m.faces, np.int64)
        if _inconsistent_winding(f):
            raise ValueError("the surface is not orientable")
    be = boundary_edges(f)
    if len(be):
        deg = np.bincount(be.ravel(), minlength=len(v))
        if (deg > 2).any():  # a vertex where boundary loops touch: the remesher cannot cope
            raise ValueError("boundary loops touch at a vertex")
    def botsch(v, f, iters):
        be = boundary_edges(f)
        u, g = gpytoolbox.remesh_botsch(
            np.ascontiguousarray(v),
            np.ascontiguousarray(f.astype(np.int32)),
            i=int(iters),
            h=float(target_edge),
            project=True,
            feature_edges=np.ascontiguousarray(be.astype(np.int32)) if len(be) else None,
        )
        return drop_unused_vertices(np.asarray(u, np.float64), np.asarray(g, np.int64))

    v, f = botsch(v, f, iterations)
    if not len(be):
        return v, f
    # The boundary polylines stay fixed, so their irregular spacing survives as short edges and
    # slivers along the openings: coarsen them, remesh once more around the new polylines, then
    # clean what that leaves (see `mesh_cleanup`).
    v, f = collapse_short_edges(v, f, SHORT_EDGE_RATIO * target_edge)
    v, f = botsch(v, f, max(iterations // 2, 1))
    for _ in range(3):
        v, f = remove_flat_ears(v, f)
        v, f = collapse_short_edges(v, f, SHORT_EDGE_RATIO * target_edge)
        f = flip_to_delaunay(v, f)
    return v, f
