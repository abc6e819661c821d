"""Training samples on the real pipeline: garment templates × Anny shapes and poses × materials.

Each sample is fully determined by its seed: which training garment, which posed body of the
body pool, which material. The body pool (posed, shaped Anny bodies with their skinning
transforms) is computed once per source, so the body model is not on the training hot path; the
samples are built by the drape pipeline (`physdrape.pipeline`), which fits each garment's
skinning transfer once, on first use.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from physdrape.body.pool import BodyPool
from physdrape.garments.split import SPLIT_FORMAT, load_or_generate
from physdrape.model import DrapeInput
from physdrape.physics import Material
from physdrape.pipeline import DrapePipeline, Job, Template

#: HOOD's training ranges (DESIGN.md Sec. 4b).
MU_RANGE = (1.59e4, 6.36e4)  # Pa, log-uniform
LAMBDA_RANGE = (3.5e3, 9.33e4)  # Pa, uniform
K_BEND_RANGE = (6.4e-8, 1.3e-3)  # J, log-uniform
DENSITY_RANGE = (0.043, 0.7)  # kg/m², uniform


def default_split_dir(seed: int = 0) -> Path:
    """Where the generated garment split is cached: ~/.cache/physdrape/garment_split_seed<seed>_v<format>."""
    version = SPLIT_FORMAT.rsplit("/", 1)[-1]
    return Path.home() / ".cache" / "physdrape" / f"garment_split_seed{seed}_v{version}"


@dataclass(frozen=True)
class DataConfig:
    """split_dir: garment split ("" = the default cache; garments are generated on first use, only
    those read); split_seed: its seed; subset: "train" or "test"; max_garments: use the first N
    (0 = all); body_pool_size: posed bodies precomputed; body_seed: seed of their shapes and
    poses; materials: "sampled" (HOOD's ranges) or "default"; dtype: of garments and bodies
    ("float32"/"float64")."""

    split_dir: str = ""
    split_seed: int = 0
    subset: str = "train"
    max_garments: int = 0
    body_pool_size: int = 128
    body_seed: int = 0
    materials: str = "sampled"
    dtype: str = "float32"

    def __post_init__(self) -> None:
        if self.materials not in ("sampled", "default"):
            raise ValueError(f"DataConfig.materials must be 'sampled' or 'default', got {self.materials!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"DataConfig.dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.max_garments < 0:
            raise ValueError(f"DataConfig.max_garments must be ≥ 0 (0 = the whole subset), got {self.max_garments}")
        if self.body_pool_size < 1:
            raise ValueError("DataConfig.body_pool_size must be ≥ 1")


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


def load_templates(config: DataConfig, *, workers: int | None = None) -> list[Template]:
    """The first `max_garments` garments of the split's `subset` (0: all of it) as templates.

    Only those garments are generated when missing (in `workers` processes, default one per CPU;
    an interrupted generation resumes), so a small `max_garments` starts in seconds.
    """
    split_dir = Path(config.split_dir).expanduser() if config.split_dir else default_split_dir(config.split_seed)
    raw = load_or_generate(split_dir, config.subset, count=config.max_garments or None, seed=config.split_seed,
                           workers=workers)
    return [Template.from_mesh(g.verts, g.faces, name=g.name) for g in raw]


class DrapeSource:
    """`SampleSource` of the real pipeline (see the module docstring)."""

    def __init__(self, config: DataConfig = DataConfig(), *, body=None,
                 templates: list[Template] | None = None) -> None:
        from physdrape.body.anny_body import get_anny_body

        self.config = config
        self.dtype = getattr(torch, config.dtype)
        self.body = body if body is not None else get_anny_body()
        self.templates = templates if templates is not None else load_templates(config)
        if not self.templates:
            raise ValueError("no garment templates to train on: check DataConfig.split_dir / subset / max_garments")
        self.pool = BodyPool(self.body, config.body_pool_size, seed=config.body_seed, dtype=self.dtype)
        self.pipeline = DrapePipeline(self.body, dtype=self.dtype)

    def make_batch(self, seeds: list[int]) -> DrapeInput:
        """The samples of `seeds`: each seed draws a training garment, a pool body and a material."""
        jobs, body_ids = [], []
        for k, seed in enumerate(seeds):
            rng = np.random.default_rng(seed)
            g = int(rng.integers(len(self.templates)))
            body_ids.append(int(rng.integers(len(self.pool))))
            material = sample_material(rng) if self.config.materials == "sampled" else Material()
            jobs.append(Job(self.templates[g], k, material))
        return self.pipeline.build(jobs, self.pool.state(body_ids))
