"""numpy front-ends of the torch geometry, for the garment tools (numpy arrays, called in loops).

- `vertex_normals(verts, faces)`: `physdrape.geometry.garment.vertex_normals` (area-weighted).
- `BodyDistance(verts, faces)`: signed distance, closest point and outward normal of points
  against a closed body: `physdrape.geometry.proximity.BodySurface` (winding-number sign,
  float64 closest points).

Torch runs on one thread inside these calls: garment meshes have a few thousand vertices, where
intra-op threads only add synchronisation, which costs more than the work on a busy machine.
"""

from __future__ import annotations

import numpy as np
import torch

from physdrape.geometry import garment as _garment
from physdrape.geometry.proximity import BodySurface
from physdrape.threads import single_torch_thread

__all__ = ["vertex_normals", "BodyDistance"]


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals, shape (V, 3) float64 (zero for unused vertices)."""
    with single_torch_thread():
        x = torch.from_numpy(np.asarray(verts, np.float64))
        return _garment.vertex_normals(x, torch.from_numpy(np.asarray(faces, np.int64))).numpy()


class BodyDistance:
    """Signed distance to a fixed closed body, for numpy points.

    Args:
        verts: body vertex positions [m], shape (Vb, 3).
        faces: outward-wound body triangles, shape (Fb, 3) int.
    """

    def __init__(self, verts: np.ndarray, faces: np.ndarray):
        with single_torch_thread():
            self.surface = BodySurface(torch.from_numpy(np.array(verts, np.float64)),
                                       torch.from_numpy(np.asarray(faces, np.int64)))

    def __call__(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Query points [m], shape (N, 3).

        Returns:
            dist: signed distance [m], negative inside the body, shape (N,).
            closest: closest point on the body triangles [m], shape (N, 3).
            normal: unit outward direction at the closest point, shape (N, 3).
        """
        x = np.array(points, np.float64).reshape(-1, 3)
        if len(x) == 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3))
        with single_torch_thread(), torch.no_grad():
            q = self.surface.query(torch.from_numpy(x))
            return q.signed_distance.numpy(), q.closest.numpy(), q.normal.numpy()
