"""Colours of the pictures: the body, penetrations, the background, and a fabric colour per material.

Each preset of `MATERIAL_PRESETS` has its own fixed colour (silk rose, cotton teal, denim indigo,
leather brown). Any other material gets a colour on the same scale, placed by how stiff and heavy
it is: its *stiffness coordinate* is the mean over (μ, λ, k_bend, ρ_A) of the value's log-position
in the trained range (0 = the range's low end, 1 = its high end), and its colour is interpolated
between the presets' colours at their own coordinates. So a fabric a little stiffer than cotton
looks a little towards denim, and the same material always gets the same colour.
"""

from __future__ import annotations

import math

import numpy as np

from physdrape.physics.material import Material
from physdrape.physics.presets import MATERIAL_PRESETS, TRAINED_RANGES

__all__ = ["BACKGROUND_RGB", "BODY_RGB", "FABRIC_RGB", "PENETRATION_RGB", "fabric_color", "material_caption",
           "preset_name", "stiffness_coordinate"]

BODY_RGB = np.array([0.80, 0.74, 0.68])
PENETRATION_RGB = np.array([0.90, 0.05, 0.05])
BACKGROUND_RGB = np.array([1.0, 1.0, 1.0])

#: The colour of each material preset, RGB in [0, 1].
FABRIC_RGB: dict[str, tuple[float, float, float]] = {
    "silk": (0.82, 0.38, 0.56),  # rose
    "cotton": (0.22, 0.60, 0.55),  # teal
    "denim": (0.20, 0.28, 0.58),  # indigo
    "leather": (0.50, 0.29, 0.14),  # saddle brown
}


def preset_name(material: Material) -> str | None:
    """The name of the preset equal to `material`, or None for any other material."""
    return next((name for name, preset in MATERIAL_PRESETS.items() if preset == material), None)


def stiffness_coordinate(material: Material) -> float:
    """Mean log-position of μ, λ, k_bend and ρ_A in the trained ranges (0 soft/light … 1 stiff/heavy),
    clipped to [0, 1]."""
    parts = []
    for field, (lo, hi) in TRAINED_RANGES.items():
        value = max(float(getattr(material, field)), 1e-30)
        parts.append((math.log(value) - math.log(lo)) / (math.log(hi) - math.log(lo)))
    return float(np.clip(np.mean(parts), 0.0, 1.0))


def fabric_color(material: Material) -> np.ndarray:
    """The fabric's colour, RGB in [0, 1], shape (3,): the preset's own colour, or for any other
    material the presets' colours interpolated at its stiffness coordinate."""
    name = preset_name(material)
    if name in FABRIC_RGB:
        return np.array(FABRIC_RGB[name])
    anchors = sorted((stiffness_coordinate(MATERIAL_PRESETS[n]), n) for n in FABRIC_RGB)
    t = stiffness_coordinate(material)
    xs = [a for a, _ in anchors]
    return np.array([np.interp(t, xs, [FABRIC_RGB[n][c] for _, n in anchors]) for c in range(3)])


def material_caption(material: Material) -> tuple[str, list[str]]:
    """A short name ("cotton", or "custom") and lines of its key constants in short form."""
    name = preset_name(material) or "custom"
    return name, [f"k_bend {material.k_bend:.2g} J · ρ_A {material.density * 1e3:.0f} g/m²",
                  f"μ {material.mu / 1e3:.3g} kPa · λ {material.lam / 1e3:.3g} kPa"]
