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


def layered_tubes(sphere_radius: float, separation: float | None = None) -> DrapeInput:
    """One float64 garment of two tubes over a sphere, radii 0.14 (inner) and 0.16 m, each outer
    vertex paired with the inner vertex under it along the inner tube's horizontal normal
    (`LayerOrder.build`; `separation` the pairs' separation on the template, None: the default
    gap); the layer order on the input's cloth."""
    from dataclasses import replace

    from physdrape.physics.layers import LayerOrder

    inner, outer = tube(4, 12, 0.14, dtype=torch.float64), tube(4, 12, 0.16, dtype=torch.float64)
    garment = Garment.from_mesh(torch.cat([inner.rest, outer.rest]),
                                torch.cat([inner.faces, outer.faces + inner.num_verts]), name="two_layers",
                                dtype=torch.float64)
    batch = make_input([garment], [sphere_radius], dtype=torch.float64)
    n = inner.num_verts
    pairs = torch.stack([torch.arange(n) + n, torch.arange(n)], dim=1)
    normal = torch.nn.functional.normalize(batch.x_init[:n] * torch.tensor([1.0, 0.0, 1.0], dtype=torch.float64),
                                           dim=1)
    gap = None if separation is None else torch.full((n,), separation, dtype=torch.float64)
    return replace(batch, cloth=replace(batch.cloth, layers=LayerOrder.build(pairs, normal, separation=gap)))

