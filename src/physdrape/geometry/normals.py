"""Normals of triangle meshes (torch, batched, differentiable): face normals and area-weighted
vertex normals.

Area-weighted vertex normals are the one implementation for garments (`geometry.garment`, the
model's features) and bodies (`body.model`, Anny/SMPL states). Angle-weighted pseudo-normals
(Baerentzen & Aanaes 2005) are a different quantity, used by the body-surface queries for inside
tests and for the direction of points on the surface (`geometry.surface_normals`).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = [
    "vertex_face_table",
    "vertex_normals",
    "face_normals",
    "triangle_normals",
]


def vertex_face_table(faces: Tensor, num_verts: int) -> Tensor:
    """Incident faces of each vertex, padded with the index F, shape (V, max degree) int64.

    Precompute once per topology for `vertex_normals(..., table=...)`: for one mesh at a time
    (a body), a gather and a sum are faster than a scatter.
    """
    num_faces = faces.shape[0]
    v = faces.reshape(-1).cpu()  # built on the host once per topology, then moved to the faces' device
    f = torch.arange(num_faces, device=v.device).repeat_interleave(3)
    order = torch.argsort(v, stable=True)
    v, f = v[order], f[order]
    deg = torch.bincount(v, minlength=num_verts)
    start = torch.cumsum(deg, 0) - deg
    slot = torch.arange(len(v), device=v.device) - start[v]
    table = torch.full((num_verts, int(deg.max()) if len(v) else 1), num_faces, dtype=torch.long, device=v.device)
    table[v, slot] = f
    return table.to(faces.device)


def vertex_normals(x: Tensor, faces: Tensor, *, table: Tensor | None = None) -> Tensor:
    """Area-weighted unit vertex normals, x of shape (..., V, 3) → (..., V, 3).

    Follows the faces' winding (counter-clockwise seen from the side the normal points to), so
    outward for a consistently oriented closed surface. A vertex in no face gets a zero normal.

    Args:
        x: vertex positions [m], shape (..., V, 3).
        faces: triangles, shape (F, 3) int64.
        table: optional `vertex_face_table(faces, V)` (same result, faster for one mesh).
    """
    x0, x1, x2 = x[..., faces[:, 0], :], x[..., faces[:, 1], :], x[..., faces[:, 2], :]
    face_n = torch.linalg.cross(x1 - x0, x2 - x0)  # length = 2 × area: area weighting
    if table is None:
        normals = torch.zeros_like(x)
        normals.index_add_(-2, faces.reshape(-1), face_n.repeat_interleave(3, dim=-2))
    else:
        padded = torch.cat([face_n, face_n.new_zeros(face_n.shape[:-2] + (1, 3))], dim=-2)
        normals = padded[..., table, :].sum(-2)
    return normals / normals.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(x.dtype).tiny)


def face_normals(verts: Tensor, faces: Tensor) -> Tensor:
    """Unit face normals (right-handed winding), shape (..., F, 3); zero for degenerate faces.

    Args:
        verts: vertex positions [m], shape (..., Vb, 3).
        faces: triangles, shape (F, 3) int64.
    """
    return triangle_normals(verts[..., faces, :])


def triangle_normals(corners: Tensor) -> Tensor:
    """Unit normals of triangles given as corners, shape (..., 3, 3) -> (..., 3); zero if degenerate."""
    n = torch.cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :], dim=-1)
    length = n.norm(dim=-1, keepdim=True)
    return n / torch.where(length > 0, length, torch.ones_like(length))

