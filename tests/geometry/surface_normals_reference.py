"""Slow torch twin of the Warp surface-normal kernels (`physdrape.geometry.surface_normals`):
face, edge and angle-weighted vertex normals as batched torch ops."""

import torch
from torch import Tensor


def unit(v: Tensor) -> Tensor:
    """v / ‖v‖ along the last dimension, zero where v is zero."""
    length = v.norm(dim=-1, keepdim=True)
    return v / torch.where(length > 0, length, torch.ones_like(length))


def angle_weighted_vertex_normals(verts: Tensor, faces: Tensor) -> Tensor:
    """Angle-weighted unit vertex normals (the vertex pseudo-normal) of verts (..., Vb, 3), faces (F, 3)."""
    corners = [verts[..., faces[:, k], :] for k in range(3)]
    fn = unit(torch.linalg.cross(corners[1] - corners[0], corners[2] - corners[0]))
    out = torch.zeros_like(verts)
    for k in range(3):
        e1, e2 = corners[(k + 1) % 3] - corners[k], corners[(k + 2) % 3] - corners[k]
        cos = (e1 * e2).sum(-1) / (e1.norm(dim=-1) * e2.norm(dim=-1)).clamp_min(torch.finfo(verts.dtype).tiny)
        out.index_add_(-2, faces[:, k], fn * torch.acos(cos.clamp(-1.0, 1.0))[..., None])
    return unit(out)


def surface_normals(verts: Tensor, faces: Tensor, neighbours: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """`physdrape.geometry.surface_normals.surface_normals` in torch ops (same arguments and results)."""
    verts, faces, neighbours = verts.double(), faces.long(), neighbours.long()
    fn = unit(torch.linalg.cross(verts[:, faces[:, 1]] - verts[:, faces[:, 0]], verts[:, faces[:, 2]] - verts[:, faces[:, 0]]))
    other = torch.where((neighbours >= 0)[None, :, :, None], fn[:, neighbours.clamp_min(0)], 0.0)
    edges = fn[:, :, None, :] + other
    edges = edges / edges.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(edges.dtype).tiny)
    return fn, edges, angle_weighted_vertex_normals(verts, faces)
