"""The unit normals a body surface's queries read, for a batch of bodies sharing one triangle
topology, in three Warp launches: each face's normal, each edge's (the normalised sum of the
normals of the two faces that share it; a hole's border edge takes its one face's) and each
vertex's angle-weighted pseudo-normal (Baerentzen & Aanaes 2005: the sum of its faces' normals,
each weighted by the face's angle at the vertex). The pseudo-normal of the face, edge or vertex a
closest point lies on gives the point's side (`geometry.closest_point`); the vertices' also place
the probes that find buried vertices (`geometry.doubtful_faces`).

A body's 26k faces take three kernels instead of a few dozen torch ops over the faces and
corners (gathers, crosses, norms, arc cosines, index_adds). Not differentiated; float64.
"""

# No `from __future__ import annotations` here: Warp reads the kernels' annotations as objects.

import torch
from torch import Tensor

from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["surface_normals"]


@defined_once
def _kernels():
    """The three kernels (defined on first use; Warp caches the binaries on disk)."""
    wp = warp()
    f64 = wp.float64

    @wp.func
    def corner_angle(e1: wp.vec3d, e2: wp.vec3d):
        cos = wp.dot(e1, e2) / wp.max(wp.length(e1) * wp.length(e2), f64(2.2250738585072014e-308))
        return wp.acos(wp.clamp(cos, f64(-1.0), f64(1.0)))

    @wp.func
    def unit(v: wp.vec3d):
        length = wp.length(v)
        if length > f64(0.0):
            return v / length
        return v

    @wp.kernel(enable_backward=False)
    def face_kernel(verts: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                    face_normal: wp.array2d(dtype=wp.vec3d), vertex_sum: wp.array2d(dtype=wp.vec3d)):
        b, f = wp.tid()
        i = faces[f, 0]
        j = faces[f, 1]
        k = faces[f, 2]
        a = verts[b, i]
        c1 = verts[b, j]
        c2 = verts[b, k]
        n = unit(wp.cross(c1 - a, c2 - a))
        face_normal[b, f] = n
        wp.atomic_add(vertex_sum, b, i, corner_angle(c1 - a, c2 - a) * n)
        wp.atomic_add(vertex_sum, b, j, corner_angle(c2 - c1, a - c1) * n)
        wp.atomic_add(vertex_sum, b, k, corner_angle(a - c2, c1 - c2) * n)

    @wp.kernel(enable_backward=False)
    def edge_kernel(face_normal: wp.array2d(dtype=wp.vec3d), neighbour: wp.array2d(dtype=wp.int32),
                    edge_normal: wp.array3d(dtype=wp.vec3d)):
        b, f = wp.tid()
        own = face_normal[b, f]
        for k in range(3):
            other = neighbour[f, k]
            total = own
            if other >= 0:
                total = own + face_normal[b, other]
            edge_normal[b, f, k] = total / wp.max(wp.length(total), f64(2.2250738585072014e-308))

    @wp.kernel(enable_backward=False)
    def vertex_kernel(vertex_sum: wp.array2d(dtype=wp.vec3d), vertex_normal: wp.array2d(dtype=wp.vec3d)):
        b, v = wp.tid()
        vertex_normal[b, v] = unit(vertex_sum[b, v])

    return face_kernel, edge_kernel, vertex_kernel


@torch.no_grad()
def surface_normals(verts: Tensor, faces: Tensor, neighbours: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Unit normals of bodies verts (B, Vb, 3) [m] with triangles faces (Fb, 3) int32 and each
    face's neighbour across its edge opposite corner k, neighbours (Fb, 3) int32 (−1 on a hole's
    border), on the vertices' device: faces' (B, Fb, 3), edges' (B, Fb, 3, 3) (face f's edge
    opposite its corner k at [:, f, k]) and vertices' angle-weighted (B, Vb, 3), float64. A
    degenerate face's normal, and the pseudo-normal of a vertex in no face, are zero."""
    wp = warp()
    face_kernel, edge_kernel, vertex_kernel = _kernels()
    verts64 = verts.detach().to(torch.float64).contiguous()
    batch, num_verts, num_faces = verts64.shape[0], verts64.shape[1], faces.shape[0]
    face_normal = verts64.new_zeros(batch, num_faces, 3)
    edge_normal = verts64.new_zeros(batch, num_faces, 3, 3)
    vertex_sum, vertex_normal = verts64.new_zeros(batch, num_verts, 3), verts64.new_zeros(batch, num_verts, 3)
    if batch and num_faces:
        device = wp.device_from_torch(verts64.device)
        vec, i32 = wp.vec3d, wp.int32
        with torch_stream(verts64.device):
            wp.launch(face_kernel, dim=(batch, num_faces), device=device,
                      inputs=[launch_arg(verts64, vec), launch_arg(faces, i32)],
                      outputs=[launch_arg(face_normal, vec), launch_arg(vertex_sum, vec)])
            wp.launch(edge_kernel, dim=(batch, num_faces), device=device,
                      inputs=[launch_arg(face_normal, vec), launch_arg(neighbours, i32)],
                      outputs=[launch_arg(edge_normal, vec)])
            wp.launch(vertex_kernel, dim=(batch, num_verts), device=device, inputs=[launch_arg(vertex_sum, vec)],
                      outputs=[launch_arg(vertex_normal, vec)])
    return face_normal, edge_normal, vertex_normal
