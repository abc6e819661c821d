"""A pool of posed bodies computed once: the training and evaluation bodies, off the hot path."""

from __future__ import annotations

import torch

from physdrape.body.model import BodyState


class BodyPool:
    """Posed Anny bodies computed once: verts, rest_verts, vertex_transforms of N (shape, pose)."""

    def __init__(self, body, size: int, *, seed: int, dtype: torch.dtype, chunk: int = 16) -> None:
        from physdrape.body.poses import sample_poses
        from physdrape.body.shapes import sample_shapes

        self.faces = body.faces
        self.canonical = body.canonical_verts(dtype=dtype)
        shapes = sample_shapes(size, seed=seed, dtype=dtype)
        poses = sample_poses(body, size, seed=seed, shape=shapes, dtype=dtype)
        verts, rest, transforms = [], [], []
        with torch.no_grad():
            for start in range(0, size, chunk):
                state = body(shapes[start:start + chunk], poses[start:start + chunk])
                verts.append(state.verts)
                rest.append(state.rest_verts)
                transforms.append(state.vertex_transforms)
        self.shapes, self.poses = shapes, poses
        self.verts, self.rest_verts, self.vertex_transforms = torch.cat(verts), torch.cat(rest), torch.cat(transforms)

    def __len__(self) -> int:
        return self.verts.shape[0]

    def state(self, indices: int | list[int]) -> BodyState:
        """Bodies `indices` (one index: a batch of one) as a BodyState (normals left empty: not
        needed for LBS)."""
        rows = [indices] if isinstance(indices, int) else list(indices)
        return BodyState(verts=self.verts[rows], faces=self.faces, normals=torch.empty(0),
                         rest_verts=self.rest_verts[rows], vertex_transforms=self.vertex_transforms[rows])
