"""Sphere bodies and tube garments shared by the model tests."""

import numpy as np
import torch
import trimesh

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import open_cylinder
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput
from physdrape.physics import Cloth, Material


def sphere_bodies(radii, dtype=torch.float32) -> BodySurface:
    """Icosphere 'bodies' centred at the origin, one per radius, sharing one topology."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    verts = torch.tensor(np.asarray(sphere.vertices), dtype=dtype)
    return BodySurface(torch.stack([verts * r for r in radii]), torch.tensor(np.asarray(sphere.faces)))


def tube(rings: int, segments: int, radius: float, dtype=torch.float32, name="tube") -> Garment:
    verts, faces = open_cylinder(rings, segments, radius=radius, length=0.3)
    verts[:, 1] -= 0.15  # centred on the sphere; partly inside it where radius < sphere's
    return Garment.from_mesh(verts, faces, name=name, dtype=dtype)


def make_input(garments, radii, materials=None, dtype=torch.float32) -> DrapeInput:
    batch = GarmentBatch.pack(garments)
    cloth = Cloth.build(batch, materials or Material())
    return DrapeInput(batch, cloth, batch.rest.clone(), sphere_bodies(radii, dtype), batch.vert_garment)
