"""Gravity: potential energy per vertex and its force (paper Eq. 3)."""

from __future__ import annotations

from torch import Tensor

from physdrape.physics.cloth import Cloth


def gravity_energy(x: Tensor, cloth: Cloth) -> Tensor:
    """E_grav per vertex = −m_i g·x_i = m_i |g| y_i [J], x (..., V, 3) → (..., V)."""
    g = cloth.gravity[cloth.vert_garment]  # (V, 3)
    return -cloth.mass * (x * g).sum(-1)


def gravity_forces(x: Tensor, cloth: Cloth) -> Tensor:
    """f_i = m_i g [N], broadcast to x's shape (..., V, 3)."""
    return (cloth.mass[:, None] * cloth.gravity[cloth.vert_garment]).expand_as(x).clone()
