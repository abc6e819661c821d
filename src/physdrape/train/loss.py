"""The self-supervised loss (paper Sec. 3.6): L = E_strain + E_bend + E_coll + E_grav at X*."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from physdrape.geometry.proximity import BodySurface
from physdrape.physics.bending import bend_energy
from physdrape.physics.cloth import Cloth
from physdrape.physics.collision import DEFAULT_MARGIN, DEFAULT_STIFFNESS, collision_energy
from physdrape.physics.gravity import gravity_energy
from physdrape.physics.strain import strain_energy


@dataclass(frozen=True)
class LossConfig:
    """collision_stiffness: k_c [J/m³]; margin: ε [m] of E_coll (DESIGN.md Sec. 2)."""

    collision_stiffness: float = DEFAULT_STIFFNESS
    margin: float = DEFAULT_MARGIN


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


def drape_loss(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, config: LossConfig) -> tuple[Tensor, dict[str, Tensor]]:
    """The training loss: the sum of the terms per garment, averaged over the batch.

    Returns the scalar loss and the batch-mean of each term (detached) for logging.
    """
    terms = drape_energies(x, cloth, bodies, body_index, config)
    loss = sum(terms.values()).mean()
    return loss, {name: value.detach().mean() for name, value in terms.items()}
