"""Private geometric queries for garment authoring and validation (Warp BVH kernels, CPU).

TODO(proximity): switch `body_signed_distance` to ``physdrape.geometry.proximity`` once it lands;
keep the signature. Positions [m]; Warp works in float32, so results are exact to ~1e-6 m.
"""

from __future__ import annotations

import numpy as np
import warp as wp

_DEVICE = "cpu"
_initialised = False


def _init() -> None:
    global _initialised
    if not _initialised:
        wp.config.quiet = True
        wp.init()
        _initialised = True


@wp.kernel
def _signed_distance_kernel(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    max_dist: float,
    dist: wp.array(dtype=float),
    closest: wp.array(dtype=wp.vec3),
    normal: wp.array(dtype=wp.vec3),
):
    tid = wp.tid()
    p = points[tid]
    q = wp.mesh_query_point_sign_winding_number(mesh, p, max_dist)
    if q.result:
        c = wp.mesh_eval_position(mesh, q.face, q.u, q.v)
        n = wp.mesh_eval_face_normal(mesh, q.face)
        d = wp.length(p - c)
        dist[tid] = q.sign * d
        closest[tid] = c
        if d > 1.0e-7:
            n = q.sign * (p - c) / d
        normal[tid] = n
    else:
        dist[tid] = max_dist
        closest[tid] = p
        normal[tid] = wp.vec3(0.0, 0.0, 0.0)


@wp.kernel
def _ray_kernel(
    mesh: wp.uint64,
    origins: wp.array(dtype=wp.vec3),
    dirs: wp.array(dtype=wp.vec3),
    max_t: float,
    t_out: wp.array(dtype=float),
):
    tid = wp.tid()
    q = wp.mesh_query_ray(mesh, origins[tid], dirs[tid], max_t)
    if q.result:
        t_out[tid] = q.t
    else:
        t_out[tid] = max_t


@wp.kernel
def _self_intersect_kernel(
    mesh: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    faces: wp.array(dtype=wp.int32, ndim=2),
    hits: wp.array(dtype=wp.int32),
):
    i = wp.tid()
    a0 = points[faces[i, 0]]
    a1 = points[faces[i, 1]]
    a2 = points[faces[i, 2]]
    lo = wp.min(wp.min(a0, a1), a2)
    hi = wp.max(wp.max(a0, a1), a2)
    query = wp.mesh_query_aabb(mesh, lo, hi)
    j = int(0)
    while wp.mesh_query_aabb_next(query, j):
        if j > i:
            shared = int(0)
            for r in range(3):
                for s in range(3):
                    if faces[i, r] == faces[j, s]:
                        shared = shared + 1
            if shared == 0:
                b0 = points[faces[j, 0]]
                b1 = points[faces[j, 1]]
                b2 = points[faces[j, 2]]
                if wp.intersect_tri_tri(a0, a1, a2, b0, b1, b2) != 0:
                    hits[i] = hits[i] + 1
                    wp.atomic_add(hits, j, 1)


class BodyQuery:
    """Closest point and winding-number sign against a fixed closed body mesh.

    Args:
        verts: body vertex positions [m], shape (Vb, 3).
        faces: body triangles, shape (Fb, 3) int.
    """

    def __init__(self, verts: np.ndarray, faces: np.ndarray):
        _init()
        self._points = wp.array(np.asarray(verts, np.float32), dtype=wp.vec3, device=_DEVICE)
        self._faces = wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32, device=_DEVICE)
        self._mesh = wp.Mesh(points=self._points, indices=self._faces)

    def __call__(self, points: np.ndarray, *, max_dist: float = 10.0):
        """Signed distance to the body (negative inside) for points [m], shape (N, 3).

        Returns:
            dist: signed distance [m], shape (N,).
            closest: closest body surface point [m], shape (N, 3).
            normal: unit outward direction from the closest point [-], shape (N, 3).
        """
        pts = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
        n = len(pts)
        if n == 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
        p = wp.array(pts, dtype=wp.vec3, device=_DEVICE)
        dist = wp.zeros(n, dtype=float, device=_DEVICE)
        closest = wp.zeros(n, dtype=wp.vec3, device=_DEVICE)
        normal = wp.zeros(n, dtype=wp.vec3, device=_DEVICE)
        wp.launch(_signed_distance_kernel, dim=n, inputs=[self._mesh.id, p, float(max_dist)],
                  outputs=[dist, closest, normal], device=_DEVICE)
        return (dist.numpy().astype(np.float64), closest.numpy().astype(np.float64),
                normal.numpy().astype(np.float64))


    def ray_distance(self, origins: np.ndarray, dirs: np.ndarray, *, max_t: float = 1.0) -> np.ndarray:
        """Distance along unit `dirs` from `origins` to the first body hit (max_t if none) [m]."""
        o = wp.array(np.ascontiguousarray(origins, np.float32), dtype=wp.vec3, device=_DEVICE)
        d = wp.array(np.ascontiguousarray(dirs, np.float32), dtype=wp.vec3, device=_DEVICE)
        t = wp.zeros(len(o), dtype=float, device=_DEVICE)
        if len(o):
            wp.launch(_ray_kernel, dim=len(o), inputs=[self._mesh.id, o, d, float(max_t)],
                      outputs=[t], device=_DEVICE)
        return t.numpy().astype(np.float64)


def self_intersecting_faces(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces of a triangle mesh that intersect a face they share no vertex with.

    Args:
        verts: vertex positions [m], shape (V, 3).
        faces: triangles, shape (F, 3) int.

    Returns:
        indices of the intersecting faces, shape (K,) int64 (empty when intersection-free).
    """
    _init()
    if len(faces) == 0:
        return np.zeros(0, np.int64)
    pts = wp.array(np.asarray(verts, np.float32), dtype=wp.vec3, device=_DEVICE)
    idx = wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32, device=_DEVICE)
    mesh = wp.Mesh(points=pts, indices=idx)
    f2 = wp.array(np.asarray(faces, np.int32), dtype=wp.int32, ndim=2, device=_DEVICE)
    hits = wp.zeros(len(faces), dtype=wp.int32, device=_DEVICE)
    wp.launch(_self_intersect_kernel, dim=len(faces), inputs=[mesh.id, pts, f2], outputs=[hits],
              device=_DEVICE)
    return np.flatnonzero(hits.numpy() > 0).astype(np.int64)
