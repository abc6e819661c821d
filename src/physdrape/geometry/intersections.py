"""Triangle-mesh intersection tests that `physdrape.geometry.proximity` does not answer.

Closest points, signed distances and inside tests against a body are
`physdrape.geometry.proximity.BodySurface`'s; this module adds the intersection queries of the
garment tools and of the oracle's guard against crossed pieces, on Warp's triangle BVH (CPU,
float32: exact to ~1e-6 m):

- `self_intersecting_faces`: faces of a garment crossing another face of the same garment;
- `self_intersecting_pairs`: the crossing face pairs themselves (to untangle them);
- `piece_crossings`: how many of those pairs join two pieces of a multi-piece garment;
- `ray_hit_distances`: how far rays travel before they hit a mesh (free space in front of a body).
"""

# No `from __future__ import annotations` here: Warp reads its functions' annotations as objects.
import numpy as np

from physdrape.warp_runtime import defined_once

__all__ = ["piece_crossings", "self_intersecting_faces", "self_intersecting_pairs", "ray_hit_distances"]

_DEVICE = "cpu"


@defined_once
def _warp():
    """Import warp and define the kernels (first call only; Warp caches the binaries on disk)."""
    from physdrape.warp_runtime import warp

    wp = warp()

    @wp.kernel(enable_backward=False)
    def ray_kernel(
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

    @wp.func
    def faces_cross(a0: wp.vec3, a1: wp.vec3, a2: wp.vec3, b0: wp.vec3, b1: wp.vec3, b2: wp.vec3) -> int:
        # Relative to a0 and in units of the pair's longest edge: wp.intersect_tri_tri snaps plane
        # distances (scaled by twice the triangle's area) below an absolute 1e-6 to zero, which in
        # metres calls centimetre triangles millimetres apart touching.
        size = wp.max(wp.max(wp.max(wp.length(a1 - a0), wp.length(a2 - a1)), wp.length(a0 - a2)),
                      wp.max(wp.max(wp.length(b1 - b0), wp.length(b2 - b1)), wp.length(b0 - b2)))
        unit = 1.0 / wp.max(size, 1e-12)
        zero = wp.vec3(0.0, 0.0, 0.0)
        return wp.intersect_tri_tri(zero, (a1 - a0) * unit, (a2 - a0) * unit, (b0 - a0) * unit,
                                    (b1 - a0) * unit, (b2 - a0) * unit)

    @wp.func
    def shared_corners(faces: wp.array(dtype=wp.int32, ndim=2), i: int, j: int) -> int:
        shared = int(0)
        for r in range(3):
            for s in range(3):
                if faces[i, r] == faces[j, s]:
                    shared = shared + 1
        return shared

    @wp.kernel(enable_backward=False)
    def self_pairs_kernel(
        mesh: wp.uint64,
        points: wp.array(dtype=wp.vec3),
        faces: wp.array(dtype=wp.int32, ndim=2),
        count: wp.array(dtype=wp.int32),
        pairs: wp.array(dtype=wp.int32, ndim=2),
    ):
        i = wp.tid()
        a0 = points[faces[i, 0]]
        a1 = points[faces[i, 1]]
        a2 = points[faces[i, 2]]
        query = wp.mesh_query_aabb(mesh, wp.min(wp.min(a0, a1), a2), wp.max(wp.max(a0, a1), a2))
        j = int(0)
        while wp.mesh_query_aabb_next(query, j):
            if j > i:
                if shared_corners(faces, i, j) == 0:
                    if faces_cross(a0, a1, a2, points[faces[j, 0]], points[faces[j, 1]], points[faces[j, 2]]) != 0:
                        k = wp.atomic_add(count, 0, 1)
                        if k < pairs.shape[0]:
                            pairs[k, 0] = i
                            pairs[k, 1] = j

    @wp.kernel(enable_backward=False)
    def cross_count_kernel(
        mesh: wp.uint64,
        points: wp.array(dtype=wp.vec3),
        faces: wp.array(dtype=wp.int32, ndim=2),
        queried: wp.array(dtype=wp.int32),
        others: wp.array(dtype=wp.int32),
        count: wp.array(dtype=wp.int32),
    ):
        # face queried[tid] against the faces of the mesh (its m-th face is faces[others[m]])
        i = queried[wp.tid()]
        a0 = points[faces[i, 0]]
        a1 = points[faces[i, 1]]
        a2 = points[faces[i, 2]]
        query = wp.mesh_query_aabb(mesh, wp.min(wp.min(a0, a1), a2), wp.max(wp.max(a0, a1), a2))
        m = int(0)
        while wp.mesh_query_aabb_next(query, m):
            j = others[m]
            if shared_corners(faces, i, j) == 0:
                if faces_cross(a0, a1, a2, points[faces[j, 0]], points[faces[j, 1]], points[faces[j, 2]]) != 0:
                    wp.atomic_add(count, 0, 1)

    return wp, ray_kernel, self_pairs_kernel, cross_count_kernel


def _mesh(wp, verts: np.ndarray, faces: np.ndarray):
    """A Warp BVH over a triangle mesh (it keeps its float32 points and indices alive)."""
    points = wp.array(np.asarray(verts, np.float32), dtype=wp.vec3, device=_DEVICE)
    indices = wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32, device=_DEVICE)
    return wp.Mesh(points=points, indices=indices)


def self_intersecting_faces(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces of a triangle mesh that intersect a face they share no vertex with.

    Args:
        verts: vertex positions [m], shape (V, 3).
        faces: triangles, shape (F, 3) int.

    Returns:
        indices of the intersecting faces, shape (K,) int64 (empty when intersection-free).
    """
    return np.unique(self_intersecting_pairs(verts, faces).ravel())


def self_intersecting_pairs(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The pairs (i, j), i < j, of faces that intersect while sharing no vertex.

    Args:
        verts: vertex positions [m], shape (V, 3); faces: triangles, shape (F, 3) int.

    Returns:
        shape (K, 2) int64, sorted (empty when intersection-free).
    """
    if len(faces) == 0:
        return np.zeros((0, 2), np.int64)
    wp, _, kernel, _ = _warp()
    mesh = _mesh(wp, verts, faces)
    f2 = wp.array(np.asarray(faces, np.int32), dtype=wp.int32, ndim=2, device=_DEVICE)
    capacity = max(1024, 4 * len(faces))
    while True:
        count = wp.zeros(1, dtype=wp.int32, device=_DEVICE)
        pairs = wp.zeros((capacity, 2), dtype=wp.int32, device=_DEVICE)
        wp.launch(kernel, dim=len(faces), inputs=[mesh.id, mesh.points, f2], outputs=[count, pairs],
                  device=_DEVICE)
        n = int(count.numpy()[0])
        if n <= capacity:
            break
        capacity = n
    out = pairs.numpy()[:n].astype(np.int64)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


def piece_crossings(verts: np.ndarray, faces: np.ndarray, piece: np.ndarray | None = None) -> int:
    """How many intersecting face pairs (as `self_intersecting_pairs` finds them) have their faces
    on different pieces: one piece passing through another, which the layer order's pairs, fixed
    on the template, do not see once the pieces have slid far over each other.

    Each piece's faces are tested against a BVH of the faces of the pieces after it, so a face
    meets only the other pieces' faces near it, not its own piece's neighbours.

    Args:
        verts: vertex positions [m], shape (V, 3); faces: triangles, shape (F, 3) int.
        piece: the piece of each vertex, shape (V,) int (default: the mesh's connected components).
    """
    faces = np.asarray(faces, np.int64)
    if piece is None:
        from physdrape.geometry.topology import connected_components

        piece = connected_components(len(verts), faces)
    owner = np.asarray(piece)[faces[:, 0]] if len(faces) else np.zeros(0, np.int64)
    pieces = np.unique(owner)
    if len(pieces) < 2:
        return 0
    wp, _, _, kernel = _warp()
    points = wp.array(np.asarray(verts, np.float32), dtype=wp.vec3, device=_DEVICE)
    faces32 = faces.astype(np.int32)
    f2 = wp.array(faces32, dtype=wp.int32, ndim=2, device=_DEVICE)
    count = wp.zeros(1, dtype=wp.int32, device=_DEVICE)
    for p in pieces[:-1]:
        queried, others = (np.flatnonzero(pick).astype(np.int32) for pick in (owner == p, owner > p))
        mesh = wp.Mesh(points=points, indices=wp.array(faces32[others].ravel(), dtype=wp.int32, device=_DEVICE))
        wp.launch(kernel, dim=len(queried), device=_DEVICE, outputs=[count],
                  inputs=[mesh.id, points, f2, wp.array(queried, dtype=wp.int32, device=_DEVICE),
                          wp.array(others, dtype=wp.int32, device=_DEVICE)])
    return int(count.numpy()[0])


def ray_hit_distances(
    verts: np.ndarray, faces: np.ndarray, origins: np.ndarray, dirs: np.ndarray, *, max_t: float = 1.0
) -> np.ndarray:
    """Distance along each unit ray to its first hit on a triangle mesh [m] (`max_t` if none).

    Args:
        verts: mesh vertex positions [m], shape (V, 3); faces: shape (F, 3) int.
        origins: ray origins [m], shape (N, 3); dirs: unit ray directions, shape (N, 3).
        max_t: the longest distance looked at [m].

    Returns:
        shape (N,) float64.
    """
    origins = np.ascontiguousarray(origins, np.float32).reshape(-1, 3)
    if len(origins) == 0:
        return np.zeros(0)
    wp, kernel, _, _ = _warp()
    mesh = _mesh(wp, verts, faces)
    o = wp.array(origins, dtype=wp.vec3, device=_DEVICE)
    d = wp.array(np.ascontiguousarray(dirs, np.float32).reshape(-1, 3), dtype=wp.vec3, device=_DEVICE)
    t = wp.zeros(len(origins), dtype=float, device=_DEVICE)
    wp.launch(kernel, dim=len(origins), inputs=[mesh.id, o, d, float(max_t)], outputs=[t], device=_DEVICE)
    return t.numpy().astype(np.float64)
