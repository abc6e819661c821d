"""The fabrics of the training data: HOOD's ranges of the material constants (DESIGN.md Sec. 4b)."""

from __future__ import annotations

import math

import numpy as np

from physdrape.physics import Material

#: HOOD's training ranges (DESIGN.md Sec. 4b).
MU_RANGE = (1.59e4, 6.36e4)  # Pa, log-uniform
LAMBDA_RANGE = (3.5e3, 9.33e4)  # Pa, uniform
K_BEND_RANGE = (6.4e-8, 1.3e-3)  # J, log-uniform
DENSITY_RANGE = (0.043, 0.7)  # kg/m², uniform


def sample_material(rng: np.random.Generator) -> Material:
    """A fabric from HOOD's ranges (μ, k_bend log-uniform; λ, density uniform)."""

    def log_uniform(lo: float, hi: float) -> float:
        return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))

    return Material(
        mu=log_uniform(*MU_RANGE),
        lam=float(rng.uniform(*LAMBDA_RANGE)),
        k_bend=log_uniform(*K_BEND_RANGE),
        density=float(rng.uniform(*DENSITY_RANGE)),
    )


def draw_material(rng: np.random.Generator, materials: str) -> Material:
    """The fabric of a training sample: drawn from HOOD's ranges ("sampled") or the default
    ("default", `DataConfig.materials`)."""
    return sample_material(rng) if materials == "sampled" else Material()
