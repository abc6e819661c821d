"""The internal active force f_int (paper Eq. 4) and the garment's energy terms."""

from __future__ import annotations

from torch import Tensor

from physdrape.physics.bending import bend_energy, bend_forces
from physdrape.physics.cloth import Cloth
from physdrape.physics.gravity import gravity_energy, gravity_forces
from physdrape.physics.strain import strain_energy, strain_forces


def internal_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_int = f_strain + f_bend + f_grav [N], x (..., V, 3) → (..., V, 3); equals −∇(E_strain + E_bend + E_grav)."""
    return strain_forces(x, cloth) + bend_forces(x, cloth) + gravity_forces(x, cloth)


def energy_terms(x: Tensor, cloth: Cloth) -> dict[str, Tensor]:
    """Per-garment totals [J] of each internal energy term, x (..., V, 3) → {name: (..., G)}."""
    return {
        "strain": cloth.sum_per_garment(strain_energy(x, cloth), cloth.face_garment),
        "bend": cloth.sum_per_garment(bend_energy(x, cloth), cloth.hinge_garment),
        "gravity": cloth.sum_per_garment(gravity_energy(x, cloth), cloth.vert_garment),
    }


def internal_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_strain + E_bend + E_grav per garment [J], x (..., V, 3) → (..., G)."""
    return sum(energy_terms(x, cloth).values())
