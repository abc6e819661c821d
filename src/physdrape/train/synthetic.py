"""Tiny synthetic draping problems (open tubes around spheres) for smoke runs and tests.

They exercise the whole training path (features, GNN, solver, handler, loss, checkpoints, DDP)
in milliseconds and need neither the body model nor the garment library.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import trimesh

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import open_cylinder
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput
from physdrape.physics import Cloth, Material
from physdrape.train.data import TrainingBatch


@dataclass(frozen=True)
class SyntheticConfig:
    """rings / segments: tube resolution; sphere_subdivisions: icosphere level of the 'bodies'."""

    rings: int = 6
    segments: int = 16
    sphere_subdivisions: int = 2


class SyntheticSource:
    """Each sample: a tube of random radius and material hanging around a sphere of random size."""

    def __init__(self, config: SyntheticConfig = SyntheticConfig(), *, dtype: torch.dtype = torch.float32) -> None:
        self.config = config
        self.dtype = dtype
        sphere = trimesh.creation.icosphere(subdivisions=config.sphere_subdivisions, radius=1.0)
        self.unit_sphere = torch.tensor(np.asarray(sphere.vertices), dtype=dtype)
        self.sphere_faces = torch.tensor(np.asarray(sphere.faces))

    def make_batch(self, seeds: list[int]) -> TrainingBatch:
        garments, materials, radii = [], [], []
        for seed in seeds:
            rng = np.random.default_rng(seed)
            radius = rng.uniform(0.12, 0.18)
            verts, faces = open_cylinder(self.config.rings, self.config.segments, radius=rng.uniform(0.13, 0.2), length=0.3)
            verts[:, 1] -= rng.uniform(0.05, 0.25)
            garments.append(Garment.from_mesh(verts, faces, name=f"tube-{seed}", dtype=self.dtype))
            materials.append(Material(mu=float(np.exp(rng.uniform(np.log(1.59e4), np.log(6.36e4)))),
                                      lam=float(rng.uniform(3.5e3, 9.33e4)),
                                      k_bend=float(np.exp(rng.uniform(np.log(6.4e-8), np.log(1.3e-3)))),
                                      density=float(rng.uniform(0.043, 0.7))))
            radii.append(radius)
        batch = GarmentBatch.pack(garments)
        bodies = BodySurface(torch.stack([self.unit_sphere * r for r in radii]), self.sphere_faces)
        return TrainingBatch(DrapeInput(batch, Cloth.build(batch, materials), batch.rest.clone(), bodies,
                                        batch.vert_garment))

    def validation(self) -> list[TrainingBatch]:
        """No validation set: the tubes have no teacher drapes."""
        return []
