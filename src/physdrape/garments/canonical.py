"""The canonical body garments are authored on, as numpy: Anny with all phenotypes 0.5 in its
rest A-pose (y-up metres, facing +z).

The generator cuts and shrink-wraps garments on it, and validation checks a template's clearance
against it; both read it from here.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from physdrape.body.anny_body import get_anny_body

__all__ = ["CanonicalBody", "canonical_body"]


@dataclass(frozen=True)
class CanonicalBody:
    """What the garment tools need of the canonical body, as numpy (y-up metres, facing +z).

    Attributes:
        verts: vertex positions [m], shape (Vb, 3) float64.
        faces: triangles, shape (Fb, 3) int64.
        joints: joint (bone head) positions [m] by bone name, each shape (3,).
        vertex_bone: dominant bone per vertex, shape (Vb,) int64 into bone_labels.
        bone_labels: bone names of the rig.
    """

    verts: np.ndarray
    faces: np.ndarray
    joints: dict
    vertex_bone: np.ndarray
    bone_labels: tuple


@functools.lru_cache(maxsize=1)
def canonical_body() -> CanonicalBody:
    """The canonical body, `physdrape.body.anny_body.get_anny_body()` with all phenotypes 0.5 in
    its rest pose (built once per process)."""
    anny = get_anny_body()
    with torch.no_grad():
        shape = anny.default_shape(1, dtype=torch.float64)
        joints = anny.rest_joints(shape)[0].numpy()
        return CanonicalBody(
            verts=anny.canonical_verts(dtype=torch.float64).numpy(),
            faces=anny.faces.numpy().astype(np.int64),
            joints={name: joints[i] for i, name in enumerate(anny.joint_names)},
            vertex_bone=anny.vertex_part().numpy().astype(np.int64),
            bone_labels=tuple(anny.joint_names),
        )
