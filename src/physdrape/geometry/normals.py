"""Area-weighted vertex normals of triangle meshes (torch, batched, differentiable).

The one implementation for garments (`geometry.garment`, the model's features) and bodies
(`body.model`, Anny/SMPL states). Angle-weighted pseudo-normals for inside tests are a different
quantity: `geometry.proximity.angle_weighted_vertex_normals`.
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["vertex_face_table", "vertex_normals"]


def vertex_face_table(faces: Tensor, num_verts: int) -> Tensor:
    """Incident faces of each vertex, padded with the index F, shape (V, max degree) int64.

    Precompute once per topology for `vertex_normals(..., table=...)`: for one mesh at a time
    (a body), a gather and a sum are faster than a scatter.
    """
    num_faces = faces.shape[0]
    v = faces.reshape(-1).cpu()
    f = torch.arange(num_faces).repeat_interleave(3)
    order = torch.argsort(v, stable=True)
    v, f = v[order], f[order]
    deg = torch.bincount(v, minlength=num_verts)
    start = torch.cumsum(deg, 0) - deg
    slot = torch.arange(len(v)) - start[v]
    table = torch.full((num_verts, int(deg.max()) if len(v) else 1), num_faces, dtype=torch.long)
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
