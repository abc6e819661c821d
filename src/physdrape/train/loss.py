"""The self-supervised loss (paper Sec. 3.6): L = E_strain + E_bend + E_coll + E_grav at X*."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from physdrape.geometry.proximity import BodySurface
from physdrape.physics.bending import bend_energy
from physdrape.physics.cloth import Cloth
from physdrape.physics.collision import DEFAULT_MARGIN, DEFAULT_STIFFNESS, collision_energy
from physdrape.physics.gravity import gravity_energy
from physdrape.physics.strain import strain_energy


@dataclass(frozen=True)
class LossConfig:
    """collision_stiffness: k_c [J/m³]; margin: ε [m] of E_coll (DESIGN.md Sec. 2).

    per_garment_scale: "none" (the paper: energies in J, averaged over the batch) or "initial":
    each garment's energy is divided by a constant (no gradient) of its own, its elastic energy
    E_strain + E_bend + E_coll at X_init plus its weight × 1 cm, so that a garment starting
    hundreds of joules from equilibrium (an extreme shape or pose) does not steer the whole batch.
    """

    collision_stiffness: float = DEFAULT_STIFFNESS
    margin: float = DEFAULT_MARGIN
    per_garment_scale: str = "none"

    def __post_init__(self) -> None:
        if self.per_garment_scale not in ("none", "initial"):
            raise ValueError(f"LossConfig.per_garment_scale must be 'none' or 'initial', got {self.per_garment_scale!r}")


def drape_energies(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, config: LossConfig) -> dict[str, Tensor]:
    """Each energy term per garment [J] at positions x (ΣV, 3): {strain, bend, collision, gravity} → (G,)."""
    distance = bodies.query(x, body_index=body_index).signed_distance
    coll = collision_energy(distance, stiffness=config.collision_stiffness, margin=config.margin)
    return {
        "strain": cloth.sum_per_garment(strain_energy(x, cloth), cloth.face_garment),
        "bend": cloth.sum_per_garment(bend_energy(x, cloth), cloth.hinge_garment),
        "collision": cloth.sum_per_garment(coll, cloth.vert_garment),
        "gravity": cloth.sum_per_garment(gravity_energy(x, cloth), cloth.vert_garment),
    }


def drape_loss(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, config: LossConfig,
               x_init: Tensor | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """The training loss: the sum of the terms per garment (divided by the garment's scale when
    `config.per_garment_scale` is "initial", which needs x_init), averaged over the batch.

    Returns the scalar loss and the batch-mean of each term [J] (detached) for logging.
    """
    terms = drape_energies(x, cloth, bodies, body_index, config)
    total = sum(terms.values())
    if config.per_garment_scale == "initial":
        if x_init is None:
            raise ValueError("per_garment_scale='initial' needs x_init")
        with torch.no_grad():
            start = drape_energies(x_init, cloth, bodies, body_index, config)
            weight = cloth.sum_per_garment(cloth.mass, cloth.vert_garment) * cloth.gravity.norm(dim=-1)
            scale = start["strain"] + start["bend"] + start["collision"] + 0.01 * weight
        total = total / scale
    return total.mean(), {name: value.detach().mean() for name, value in terms.items()}
