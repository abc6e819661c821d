"""The internal active force f_int (paper Eq. 4) and the garment's energy terms.

With a grip (`physics.grip`, `Cloth.grip`) the grip term is one of them: every user of these
functions (loss, solver, oracle, metrics) then measures the same energy."""

from __future__ import annotations

from torch import Tensor

from physdrape.physics.bending import bend_energy, bend_forces
from physdrape.physics.cloth import Cloth
from physdrape.physics.gravity import gravity_energy, gravity_forces
from physdrape.physics.grip import grip_energy, grip_forces
from physdrape.physics.strain import strain_energy, strain_forces


def internal_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_int = f_strain + f_bend + f_grav (+ f_grip) [N], x (..., V, 3) → (..., V, 3); equals
    −∇(E_strain + E_bend + E_grav (+ E_grip))."""
    f = strain_forces(x, cloth) + bend_forces(x, cloth) + gravity_forces(x, cloth)
    if cloth.grip is not None:
        f = f + grip_forces(x, cloth.grip)
    return f


def energy_terms(x: Tensor, cloth: Cloth) -> dict[str, Tensor]:
    """Per-garment totals [J] of each internal energy term, x (..., V, 3) → {name: (..., G)}:
    strain, bend, gravity, and grip when the cloth has one."""
    terms = {
        "strain": cloth.sum_per_garment(strain_energy(x, cloth), cloth.face_garment),
        "bend": cloth.sum_per_garment(bend_energy(x, cloth), cloth.hinge_garment),
        "gravity": cloth.sum_per_garment(gravity_energy(x, cloth), cloth.vert_garment),
    }
    if cloth.grip is not None:
        terms["grip"] = cloth.sum_per_garment(grip_energy(x, cloth.grip), cloth.vert_garment[cloth.grip.index])
    return terms


def internal_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_strain + E_bend + E_grav (+ E_grip) per garment [J], x (..., V, 3) → (..., G)."""
    return sum(energy_terms(x, cloth).values())
