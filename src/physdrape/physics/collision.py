"""Body contact penalty: E_coll = k_c Σ ReLU(ε − d)³ on signed distances to the body surface."""

from __future__ import annotations

from torch import Tensor

#: Collision margin ε [m]; also the collision handler's margin (DESIGN.md Sec. 2).
DEFAULT_MARGIN = 2e-3
#: Penalty stiffness k_c [J/m³] (DESIGN.md Sec. 2, a config value).
DEFAULT_STIFFNESS = 2.5e3


def collision_energy(distance: Tensor, *, stiffness: float = DEFAULT_STIFFNESS, margin: float = DEFAULT_MARGIN) -> Tensor:
    """Per-vertex penalty k_c·ReLU(ε − d)³ [J], distance d [m] (..., V) → (..., V)."""
    depth = (margin - distance).clamp_min(0.0)
    return stiffness * depth * depth * depth


def collision_forces(
    distance: Tensor,
    normal: Tensor,
    *,
    stiffness: float = DEFAULT_STIFFNESS,
    margin: float = DEFAULT_MARGIN,
) -> Tensor:
    """f_i = 3 k_c ReLU(ε − d_i)² n_i [N] = −∇E_coll, since ∇_x d = n (closest point held fixed).

    distance (..., V) [m], normal: unit outward body normal at the closest point (..., V, 3).
    """
    depth = (margin - distance).clamp_min(0.0)
    return (3.0 * stiffness * depth * depth)[..., None] * normal
