"""Fabric material: the physical constants of the StVK membrane, bending, and gravity."""

from __future__ import annotations

from dataclasses import dataclass

#: SNUG's factor between the plate bending stiffness A·t³/12 and k_bend (DESIGN.md Sec. 2).
SNUG_BEND_FACTOR = 50.0


@dataclass(frozen=True)
class Material:
    """A fabric's physical constants (SI units). Defaults: SNUG's fabric (DESIGN.md Sec. 2).

    Attributes:
        mu: Lamé shear modulus μ [Pa].
        lam: Lamé first parameter λ [Pa].
        k_bend: bending stiffness k_bend [J].
        thickness: sheet thickness t [m]; strain energy is t·A·ψ.
        density: area density ρ_A [kg/m²].
        gravity: gravitational acceleration g [m/s²], acting along −y.
    """

    mu: float = 2.36e4
    lam: float = 4.44e4
    k_bend: float = 3.96e-5
    thickness: float = 4.7e-4
    density: float = 0.20022
    gravity: float = 9.81

    def __post_init__(self) -> None:
        for name in ("mu", "k_bend", "thickness", "density"):
            value = getattr(self, name)
            if not value > 0:
                raise ValueError(f"Material.{name} must be positive, got {value!r}")
        if not self.lam >= 0:
            raise ValueError(f"Material.lam must be non-negative, got {self.lam!r}")
        if not self.gravity >= 0:
            raise ValueError(f"Material.gravity is a magnitude (acting along −y) and must be ≥ 0, got {self.gravity!r}")

    @staticmethod
    def from_young_poisson(
        young: float,
        poisson: float,
        *,
        thickness: float = 4.7e-4,
        density: float = 0.20022,
        bend_factor: float = SNUG_BEND_FACTOR,
        gravity: float = 9.81,
    ) -> "Material":
        """A plane-stress fabric from Young's modulus E [Pa] and Poisson's ratio ν.

        A = E / (1 − ν²), μ = A(1 − ν)/2, λ = Aν, k_bend = bend_factor · A t³ / 12.
        """
        if not young > 0:
            raise ValueError(f"Young's modulus must be positive [Pa], got {young!r}")
        if not 0 <= poisson < 0.5:
            raise ValueError(f"Poisson's ratio must be in [0, 0.5), got {poisson!r}")
        plate = young / (1.0 - poisson**2)
        return Material(
            mu=plate * (1.0 - poisson) / 2.0,
            lam=plate * poisson,
            k_bend=bend_factor * plate * thickness**3 / 12.0,
            thickness=thickness,
            density=density,
            gravity=gravity,
        )


#: The default fabric (E = 7e4 Pa, ν = 0.485, t = 4.7e-4 m; SNUG).
DEFAULT_MATERIAL = Material()
