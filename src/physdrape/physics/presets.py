"""Named fabric presets (silk, cotton, denim, leather) inside the model's training ranges.

Where the numbers come from:
- **cotton** is the default SNUG fabric (DESIGN.md Sec. 2: E = 7e4 Pa, ν = 0.485, t = 4.7e-4 m →
  μ = 2.36e4 Pa, λ = 4.44e4 Pa, k_bend = 3.96e-5 J, ρ_A = 0.20022 kg/m²): a cotton jersey.
- **area densities** are typical fabric weights: silk charmeuse / crêpe 60–100 g/m², denim
  340–450 g/m² (12–14 oz/yd²), garment leather (lamb/goat, 0.6–0.9 mm) 550–900 g/m², clipped to
  the trained range (≤ 0.7 kg/m²).
- **stiffnesses** (μ, λ, k_bend) are *ordered*, not measured: silk near the soft end of HOOD's
  training ranges, leather near the stiff end, denim between cotton and leather; bending follows
  the drape coefficient ordering silk ≪ cotton < denim < leather. The model has only seen
  materials in these ranges (DESIGN.md Sec. 4b), so no preset leaves them:
  μ ∈ [1.59e4, 6.36e4] Pa, λ ∈ [3.5e3, 9.33e4] Pa, k_bend ∈ [6.4e-8, 1.3e-3] J,
  ρ_A ∈ [0.043, 0.7] kg/m².
"""

from __future__ import annotations

from physdrape.physics.material import Material

#: The trained ranges (HOOD's; DESIGN.md Sec. 4b): name → (low, high), SI units.
TRAINED_RANGES: dict[str, tuple[float, float]] = {
    "mu": (1.59e4, 6.36e4),  # Pa
    "lam": (3.5e3, 9.33e4),  # Pa
    "k_bend": (6.4e-8, 1.3e-3),  # J
    "density": (0.043, 0.7),  # kg/m²
}

#: Named fabrics, lightest/softest first.
MATERIAL_PRESETS: dict[str, Material] = {
    "silk": Material(mu=1.7e4, lam=2.0e4, k_bend=2.0e-7, density=0.08),
    "cotton": Material(),  # SNUG's default fabric
    "denim": Material(mu=4.5e4, lam=7.0e4, k_bend=3.0e-4, density=0.40),
    "leather": Material(mu=6.3e4, lam=9.0e4, k_bend=1.2e-3, density=0.65),
}


def material_preset(name: str) -> Material:
    """The `Material` of preset `name` (one of `MATERIAL_PRESETS`); ValueError listing them otherwise."""
    key = name.strip().lower()
    if key not in MATERIAL_PRESETS:
        raise ValueError(f"unknown material preset {name!r}; choose one of {', '.join(MATERIAL_PRESETS)} "
                         "or give --mu/--lam/--k-bend/--density")
    return MATERIAL_PRESETS[key]


def out_of_range(material: Material) -> list[str]:
    """Human-readable notes for each constant outside the trained ranges (empty when all inside)."""
    notes = []
    for field, (lo, hi) in TRAINED_RANGES.items():
        value = getattr(material, field)
        if not lo <= value <= hi:
            notes.append(f"{field} = {value:.3g} is outside the trained range [{lo:.3g}, {hi:.3g}]")
    return notes
