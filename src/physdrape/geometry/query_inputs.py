"""The checks of what a body-surface query is given (`geometry.proximity`), at the boundary only:
body vertices and faces, and query points with their bodies, with errors that say what is wrong."""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

__all__ = ["check_faces", "check_verts", "packed_points"]


def check_verts(verts: Tensor) -> Tensor:
    """Body vertex positions (Vb, 3) or (B, Vb, 3), finite floats, as (B, Vb, 3)."""
    if not isinstance(verts, Tensor) or not verts.is_floating_point():
        raise TypeError(f"body verts must be a floating-point torch.Tensor, got {type(verts).__name__}"
                        f"{'' if not isinstance(verts, Tensor) else ' of dtype ' + str(verts.dtype)}")
    if verts.ndim == 2:
        verts = verts[None]
    if verts.ndim != 3 or verts.shape[-1] != 3 or verts.shape[1] < 3:
        raise ValueError(f"body verts must have shape (Vb, 3) or (B, Vb, 3) with Vb >= 3, got {tuple(verts.shape)}")
    if verts.shape[0] < 1:
        raise ValueError("body verts hold an empty batch (B = 0)")
    if not torch.isfinite(verts).all():
        bad = torch.nonzero(~torch.isfinite(verts).all(-1))[0].tolist()
        raise ValueError(f"body verts contain NaN/inf (first at batch, vertex = {bad}); fix the body model output")
    return verts


def check_faces(faces: Tensor | np.ndarray, num_verts: int, device: torch.device) -> Tensor:
    """Triangles (Fb, 3) of integer indices into `num_verts` vertices, as int64 on `device`."""
    faces = torch.as_tensor(faces, device=device)
    if faces.dtype.is_floating_point or faces.dtype == torch.bool:
        raise TypeError(f"faces must be an integer tensor, got dtype {faces.dtype}")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] < 1:
        raise ValueError(f"faces must have shape (Fb, 3) with Fb >= 1, got {tuple(faces.shape)}")
    faces = faces.to(torch.int64)
    lo, hi = int(faces.min()), int(faces.max())
    if lo < 0 or hi >= num_verts:
        raise ValueError(f"indices in faces must be in [0, {num_verts}) (got {lo if lo < 0 else hi}); "
                         "faces and verts do not belong to the same mesh")
    return faces


def packed_points(points: Tensor, body_index: Tensor | None, verts: Tensor) -> tuple[Tensor, Tensor, torch.Size]:
    """Query points of a surface of bodies `verts` (B, Vb, 3) checked and flattened: (N, 3), each
    point's body (N,) int64, and the leading shape of `points` (see `BodySurface.query`)."""
    if not isinstance(points, Tensor) or not points.is_floating_point():
        raise TypeError("points must be a floating-point torch.Tensor")
    if points.dtype != verts.dtype:
        raise TypeError(f"points have dtype {points.dtype} but the body verts have {verts.dtype}; "
                        "convert one of them explicitly")
    if points.device != verts.device:
        raise ValueError(f"points are on {points.device} but the body is on {verts.device}")
    if points.shape[-1:] != (3,):
        raise ValueError(f"points must have a last dimension of 3, got shape {tuple(points.shape)}")
    lead = points.shape[:-1]
    num_bodies = verts.shape[0]
    if body_index is not None:
        if points.ndim != 2:
            raise ValueError(f"with body_index, points must be packed (N, 3), got {tuple(points.shape)}")
        body_index = torch.as_tensor(body_index, device=points.device)
        if body_index.shape != lead or body_index.dtype.is_floating_point:
            raise ValueError(f"body_index must be an integer tensor of shape ({lead[0]},), "
                             f"got {tuple(body_index.shape)} {body_index.dtype}")
        body = body_index.to(torch.int64)
        if body.numel() and (int(body.min()) < 0 or int(body.max()) >= num_bodies):
            raise ValueError(f"indices in body_index must be in [0, {num_bodies}) "
                             f"(got {int(body.min()) if int(body.min()) < 0 else int(body.max())})")
    elif points.ndim == 3:
        if points.shape[0] != num_bodies:
            raise ValueError(f"points of shape (B, N, 3) need B = {num_bodies} (the number of bodies), "
                             f"got B = {points.shape[0]}")
        body = torch.arange(num_bodies, device=points.device).repeat_interleave(points.shape[1])
    elif points.ndim == 2:
        if num_bodies != 1:
            raise ValueError(f"the surface holds {num_bodies} bodies: pass points as (B, N, 3) "
                             "or packed (N, 3) with body_index")
        body = torch.zeros(points.shape[0], dtype=torch.int64, device=points.device)
    else:
        raise ValueError(f"points must have shape (N, 3) or (B, N, 3), got {tuple(points.shape)}")
    x = points.reshape(-1, 3)
    finite = torch.isfinite(x).all(-1)
    if not finite.all():
        first = int(torch.nonzero(~finite)[0])
        raise ValueError(f"points contain NaN/inf ({int((~finite).sum())} of {x.shape[0]}, first at flat "
                         f"index {first}); the garment state diverged upstream")
    return x, body, lead
