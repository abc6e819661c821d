"""The cloth model: a garment batch and its materials turned into per-element coefficients.

This is the static part of the simulation (Newton's "model"): everything the energies and forces
need except the positions x, precomputed once per batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import torch
from torch import Tensor

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.physics.grip import Grip
from physdrape.physics.layers import LayerOrder
from physdrape.physics.material import DEFAULT_MATERIAL, Material
from physdrape.physics.stitches import Stitches
from physdrape.tensor_memo import IdentityMemo, TensorMemo


@dataclass(frozen=True)
class Cloth:
    """Per-element physics coefficients of a packed garment batch (one dtype).

    Attributes:
        faces: (F, 3) int64; rest_inv: Dm⁻¹ (F, 2, 2) [1/m];
        volume: reference volume t·A of each face (F,) [m³];
        mu, lam: Lamé parameters per face (F,) [Pa];
        hinges: (H, 4) int64 [v0, v1 shared edge, v2, v3];
        bend_stiffness: k_bend · l₀² / (4(A₀ + A₁)) per hinge (H,) [J];
        mass: vertex masses (V,) [kg]; gravity: acceleration vector (G, 3) [m/s²] per garment;
        vert_garment, face_garment, hinge_garment: owning garment per element; num_garments: G.
        stiffness: (μ [Pa], λ [Pa], k_bend [J]) of each garment's material, (G, 3).
        grip: the gripping vertices' tangential anchors (`physics.grip`), or None.
        stitches: closures tying vertex pairs (`physics.stitches`), or None.
        layers: outer-over-inner pairs of a multi-piece garment (`physics.layers`), or None.
    All tensors live on the device of the garment batch it was built from (`to` moves them).
    """

    faces: Tensor
    rest_inv: Tensor
    volume: Tensor
    mu: Tensor
    lam: Tensor
    hinges: Tensor
    bend_stiffness: Tensor
    mass: Tensor
    gravity: Tensor
    vert_garment: Tensor
    face_garment: Tensor
    hinge_garment: Tensor
    num_garments: int
    stiffness: Tensor
    grip: Grip | None = None
    stitches: Stitches | None = None
    layers: LayerOrder | None = None

    @staticmethod
    def build(garments: GarmentBatch | Garment, materials: Material | Sequence[Material] = DEFAULT_MATERIAL) -> "Cloth":
        """Coefficients for a batch; `materials` is one for all garments or one per garment. The
        same batch object in the same materials gives the same cloth object again."""
        batch = garments if isinstance(garments, GarmentBatch) else GarmentBatch.pack(garments)
        mats = [materials] * batch.num_garments if isinstance(materials, Material) else list(materials)
        if len(mats) != batch.num_garments:
            raise ValueError(f"got {len(mats)} materials for {batch.num_garments} garments: give one, or one per garment")
        return _BUILT.get((batch,), tuple(mats), lambda: Cloth._build(batch, mats))

    @staticmethod
    def _build(batch: GarmentBatch, mats: list[Material]) -> Cloth:
        dtype, device = batch.dtype, batch.device

        def per_garment(name: str) -> Tensor:
            return torch.tensor([getattr(m, name) for m in mats], dtype=dtype, device=device)

        rest, hinges = batch.rest, batch.hinges
        x0, x1, x2, x3 = (rest[hinges[:, k]] for k in range(4))
        edge = x1 - x0
        area_sum = 0.5 * (torch.linalg.cross(edge, x2 - x0).norm(dim=-1) + torch.linalg.cross(edge, x3 - x0).norm(dim=-1))
        scale = (edge * edge).sum(-1) / (4.0 * area_sum)

        face_mass = per_garment("density")[batch.face_garment] * batch.rest_area / 3.0
        mass = torch.zeros(batch.num_verts, dtype=dtype, device=device).index_add_(0, batch.faces.reshape(-1),
                                                                               face_mass.repeat_interleave(3))
        gravity = torch.zeros(batch.num_garments, 3, dtype=dtype, device=device)
        gravity[:, 1] = -per_garment("gravity")
        return Cloth(
            faces=batch.faces,
            rest_inv=batch.rest_inv,
            volume=per_garment("thickness")[batch.face_garment] * batch.rest_area,
            mu=per_garment("mu")[batch.face_garment],
            lam=per_garment("lam")[batch.face_garment],
            hinges=hinges,
            bend_stiffness=per_garment("k_bend")[batch.hinge_garment] * scale,
            mass=mass,
            gravity=gravity,
            vert_garment=batch.vert_garment,
            face_garment=batch.face_garment,
            hinge_garment=batch.hinge_garment,
            num_garments=batch.num_garments,
            stiffness=torch.stack([per_garment("mu"), per_garment("lam"), per_garment("k_bend")], dim=-1),
        )

    @property
    def num_verts(self) -> int:
        return self.mass.shape[0]

    @property
    def dtype(self) -> torch.dtype:
        return self.mass.dtype

    @property
    def device(self) -> torch.device:
        return self.mass.device

    def to(self, dtype: torch.dtype | None = None, *, device: torch.device | str | None = None) -> "Cloth":
        """The same cloth with floating tensors in `dtype` (None: kept) and every tensor on
        `device` (None: kept)."""
        changes = {f.name: value.to(device=device, dtype=dtype if value.is_floating_point() else None)
                   for f in fields(self) if isinstance(value := getattr(self, f.name), Tensor)}
        if self.grip is not None:
            changes["grip"] = self.grip.to(dtype, device=device)
        if self.stitches is not None:
            changes["stitches"] = self.stitches.to(dtype, device=device)
        if self.layers is not None:
            changes["layers"] = self.layers.to(dtype, device=device)
        return replace(self, **changes)

    def with_terms_of(self, other: Cloth) -> Cloth:
        """This cloth with `other`'s grip, stitches and layer order (in this cloth's dtype and device)."""
        return replace(self, **{name: None if (term := getattr(other, name)) is None
                                else term.to(self.dtype, device=self.device) for name in ("grip", "stitches", "layers")})

    def sum_per_garment(self, values: Tensor, owner: Tensor) -> Tensor:
        """Sum per-element values (..., N) into per-garment totals (..., G) using `owner` (N,)."""
        out = values.new_zeros(*values.shape[:-1], self.num_garments)
        return out.index_add_(-1, owner, values)

    def sum_vertex_field(self, values: Tensor) -> Tensor:
        """Per garment, the sum of every entry of a per-vertex field (V, ...) → (G,): with values
        = a * b, the garments' dot products of the fields a and b. A garment's vertices are
        consecutive rows (`GarmentBatch.pack`), so each garment's rows are summed as one block:
        the rows summed one by one and scattered into the garments cost several times as much on
        the CPU (a sum over a trailing dimension of 3 is slow there), and the solver forms such
        dot products dozens of times per drape."""
        spans = _VERTEX_SPANS.get(self.vert_garment, _spans)
        if spans is None:  # vertices not grouped by garment: scatter them
            return self.sum_per_garment(values.reshape(values.shape[0], -1).sum(-1), self.vert_garment)
        spans = spans + [(len(values), len(values))] * (self.num_garments - len(spans))  # garments without vertices
        return torch.stack([values[start:end].sum() for start, end in spans])


#: Cloths by batch and materials (a drape of the same garments builds its cloth once).
_BUILT = IdentityMemo(16)

#: Each garment's rows [start, end) by the owner tensor (`Cloth.sum_vertex_field`).
_VERTEX_SPANS = TensorMemo(64)


def _spans(owner: Tensor) -> list[tuple[int, int]] | None:
    """The consecutive rows [start, end) of each garment 0 … max(owner) by owner (N,) (empty where
    a garment has none), or None where the rows are not grouped by garment in ascending order."""
    if len(owner) > 1 and not bool((owner[1:] >= owner[:-1]).all()):
        return None
    ends = torch.bincount(owner).cumsum(0).tolist()
    return list(zip([0, *ends[:-1]], ends))
