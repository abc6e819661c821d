"""Drape metrics (DESIGN.md Sec. 4): one definition for training logs, `eval`, reports and the oracle."""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.garment import GarmentBatch
from physdrape.geometry.proximity import BodySurface
from physdrape.physics.bending import bend_energy
from physdrape.physics.cloth import Cloth
from physdrape.physics.forces import internal_forces
from physdrape.physics.material import DEFAULT_MATERIAL
from physdrape.physics.strain import strain_energy

#: A vertex closer to the body than this [m] counts as "too close" (HOOD's 1 mm metric).
CLOSE_DISTANCE = 1e-3
#: A vertex within this distance [m] of the body is in contact: the body may push on it, so it is
#: left out of the residual-force check (the collision margin ε plus a millimetre of slack).
CONTACT_DISTANCE = 3e-3


def faces_inside(x: Tensor, garments: GarmentBatch, bodies: BodySurface, body_index: Tensor, *,
                 bound: DistanceBound | None = None) -> Tensor:
    """Whether each face's centroid is inside its body, (ΣF,) bool: decided exactly by the
    body-surface query (winding number; no margin). x [m] (ΣV, 3); body_index (ΣV,). `bound`: a
    `DistanceBound` of the vertices and then the centroids; the centroids it proves outside are
    not queried, and it decides the side of those in doubt that cannot have crossed the surface."""
    faces = garments.faces
    centroids, owner = x[faces].mean(dim=1), body_index[faces[:, 0]]
    if bound is None:
        return bodies.query(centroids, body_index=owner).inside
    rows, query = bodies.query_within(centroids, 0.0, body_index=owner,
                                      bound=bound.part(x.shape[0], x.shape[0] + faces.shape[0]))
    inside = torch.zeros(faces.shape[0], dtype=torch.bool, device=x.device)
    inside[rows] = query.inside
    return inside


def b2g_percent(x: Tensor, garments: GarmentBatch, bodies: BodySurface, body_index: Tensor, *,
                inside: Tensor | None = None) -> Tensor:
    """Body-to-garment interpenetration: 100 · Σ_f A_f [centroid of f inside] / Σ_f A_f, per garment (G,).

    Inside is `faces_inside` (or `inside`, its result for this x, when the caller has it). Areas
    are rest areas. x: garment positions [m], (ΣV, 3); body_index: body of each vertex, (ΣV,).
    """
    if inside is None:
        inside = faces_inside(x, garments, bodies, body_index)
    area = garments.rest_area.to(x.dtype)
    owner, count = garments.face_garment, garments.num_garments
    inside_area = x.new_zeros(count).index_add_(0, owner, area * inside.to(x.dtype))
    total_area = x.new_zeros(count).index_add_(0, owner, area)
    return 100.0 * inside_area / total_area


@dataclass(frozen=True)
class DrapeMetrics:
    """Per-garment metrics of a drape, each a tensor of shape (G,).

    strain, bend: energies [J] under the default material (comparable across runs whatever
    material was draped); b2g_percent: see `b2g_percent`; close_percent: share of vertices with
    signed distance < 1 mm [%]; residual_force: mean ‖F_int‖ over vertices not in contact [N];
    residual_relative: the same, each vertex's force divided by its weight m_i·g (mean), which
    `vertex_residual` holds for every vertex (ΣV,), in contact or not (not a per-garment metric).
    """

    strain: Tensor
    bend: Tensor
    b2g_percent: Tensor
    close_percent: Tensor
    residual_force: Tensor
    residual_relative: Tensor
    vertex_residual: Tensor | None = field(default=None, compare=False, repr=False)

    def as_dict(self) -> dict[str, list[float]]:
        """The per-garment metrics by name."""
        return {name: getattr(self, name).tolist() for name in self.__dataclass_fields__ if name != "vertex_residual"}


@torch.no_grad()
def drape_metrics(x: Tensor, garments: GarmentBatch, bodies: BodySurface, body_index: Tensor, *, cloth: Cloth | None = None,
                  inside_faces: Tensor | None = None, bound: DistanceBound | None = None) -> DrapeMetrics:
    """All metrics of drapes x (ΣV, 3) [m]. `cloth` gives the materials actually draped (for the
    residual force); energies always use the default material. `inside_faces`: `faces_inside` of
    this x, when the caller has it (else it is queried). `bound`: a `DistanceBound` of the
    vertices and then the centroids; only what it leaves within `CONTACT_DISTANCE` of the body
    (vertices) or inside it (centroids) is queried."""
    reference = Cloth.build(garments.to(x.dtype), DEFAULT_MATERIAL)
    cloth = reference if cloth is None else cloth
    count = garments.num_garments
    rows, query = bodies.query_within(x, CONTACT_DISTANCE, body_index=body_index,
                                      bound=None if bound is None else bound.part(0, x.shape[0]))
    distance = query.signed_distance
    if rows is not None:  # the vertices proved farther than CONTACT_DISTANCE count as that far:
        # neither close nor in contact
        distance = x.new_full((x.shape[0],), 2.0 * CONTACT_DISTANCE).index_copy(0, rows, distance)
    verts_per_garment = x.new_zeros(count).index_add_(0, garments.vert_garment, torch.ones_like(distance))
    close = x.new_zeros(count).index_add_(0, garments.vert_garment, (distance < CLOSE_DISTANCE).to(x.dtype))
    force = internal_forces(x, cloth).norm(dim=-1)
    weight = cloth.mass * cloth.gravity[cloth.vert_garment].norm(dim=-1)
    free = (distance > CONTACT_DISTANCE).to(x.dtype)
    free_count = x.new_zeros(count).index_add_(0, garments.vert_garment, free).clamp_min(1.0)
    residual = x.new_zeros(count).index_add_(0, garments.vert_garment, force * free) / free_count
    vertex_residual = force / weight
    relative = x.new_zeros(count).index_add_(0, garments.vert_garment, vertex_residual * free) / free_count
    return DrapeMetrics(
        strain=reference.sum_per_garment(strain_energy(x, reference), reference.face_garment),
        bend=reference.sum_per_garment(bend_energy(x, reference), reference.hinge_garment),
        b2g_percent=b2g_percent(x, garments, bodies, body_index,
                                inside=faces_inside(x, garments, bodies, body_index, bound=bound)
                                if inside_faces is None else inside_faces),
        close_percent=100.0 * close / verts_per_garment,
        residual_force=residual,
        residual_relative=relative,
        vertex_residual=vertex_residual,
    )
