"""A pool of posed bodies computed once: the training and evaluation bodies, off the hot path."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from physdrape.body.model import BodyState


class BodyPool:
    """Posed Anny bodies computed once: verts, rest_verts, vertex_transforms of N (shape, pose).

    `BodyPool(body, size, seed=s)` draws all N shapes and poses as one batch from the generator of
    `s` (the training pool: body i depends on N). `BodyPool.from_seeds(body, seeds)` draws body i
    alone from `seeds[i]`, so a body is the same whatever pool it is in (the evaluation's
    instances, whose bodies must not change with the number drawn).
    """

    def __init__(self, body, size: int, *, seed: int, dtype: torch.dtype, chunk: int = 16) -> None:
        from physdrape.body.poses import sample_poses
        from physdrape.body.shapes import sample_shapes

        shapes = sample_shapes(size, seed=seed, dtype=dtype)
        poses = sample_poses(body, size, seed=seed, shape=shapes, dtype=dtype)
        self._pose(body, shapes, poses, dtype=dtype, chunk=chunk)

    @classmethod
    def from_seeds(cls, body, seeds: Sequence[int], *, dtype: torch.dtype) -> BodyPool:
        """Body i drawn from its own seed `seeds[i]` (one shape and one pose, as
        `BodyPool(body, 1, seed=seeds[i])` draws them) and posed alone, so that its vertices are
        bit for bit the same whatever the other seeds and their number."""
        from physdrape.body.poses import sample_poses
        from physdrape.body.shapes import sample_shapes

        if len(seeds) == 0:
            raise ValueError("BodyPool.from_seeds needs at least one seed")
        shapes = [sample_shapes(1, seed=int(s), dtype=dtype) for s in seeds]
        poses = [sample_poses(body, 1, seed=int(s), shape=shape, dtype=dtype) for s, shape in zip(seeds, shapes)]
        pool = cls.__new__(cls)
        pool._pose(body, torch.cat(shapes), torch.cat(poses), dtype=dtype, chunk=1)
        return pool

    def _pose(self, body, shapes: torch.Tensor, poses: torch.Tensor, *, dtype: torch.dtype, chunk: int) -> None:
        """Pose `shapes` (N, 6) × `poses` (N, J, 3) in chunks of `chunk` bodies."""
        self.faces = body.faces
        self.canonical = body.canonical_verts(dtype=dtype)
        verts, rest, transforms = [], [], []
        with torch.no_grad():
            for start in range(0, shapes.shape[0], chunk):
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
