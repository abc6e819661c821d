"""Dihedral bending: energy per interior hinge and its analytic force (paper Eq. 2).

All three run as Warp kernels (`physics.element_kernels`), differentiable in x."""

from __future__ import annotations

from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.element_kernels import (
    bend_energy_per_hinge,
    bend_force,
    hinge_angles,
)


def dihedral_angle(x: Tensor, hinges: Tensor) -> Tensor:
    """Signed dihedral angle θ of each hinge [rad], zero when flat, x (..., V, 3) → (..., H).

    θ = atan2((n_a × n_b)·ê, n_a·n_b) with the hinge's own face normals (n_a of face (v0, v1, v2),
    n_b of face (v0, v3, v1)), so the sign does not depend on the faces' winding; atan2 keeps it
    finite for any non-degenerate hinge.
    """
    return hinge_angles(x, hinges)


def bend_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_bend per hinge = k_bend · l₀²/(4(A₀+A₁)) · θ²/2 [J], x (..., V, 3) → (..., H)."""
    return bend_energy_per_hinge(x, cloth.hinges, cloth.bend_stiffness)


def bend_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_i = −Σ_e k_bend s_e θ_e ∇_{x_i} θ_e (paper Eq. 2) [N], x (..., V, 3) → (..., V, 3).

    ∇θ in closed form: the opposite corners move along their face normals with 1/height,
    the shared-edge vertices take the balancing share by the corners' projections on the edge.
    """
    return bend_force(x, cloth.hinges, cloth.bend_stiffness)
