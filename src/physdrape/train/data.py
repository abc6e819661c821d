"""Training samples on the real pipeline: garment templates × Anny shapes and poses × materials.

Each sample is fully determined by its seed. Without an instance cache (`DataConfig.instances`
empty) the seed draws a training garment, a posed body of the body pool and a material, and the
drape pipeline (`physdrape.pipeline`) builds the sample, fitting each garment's skinning transfer
once, on first use; the body pool (posed, shaped Anny bodies with their skinning transforms) is
computed once per source, so the body model is not on the training hot path. With a cache
(`physdrape.train.instances`, built on first use) the seed draws one of its instances, whose
X_init and teacher drape were written once, and a sample costs no skinning at all.

The pool's bodies are one `PosedBodies`, their surfaces (BVHs, doubtful faces) built once for
the whole pool on first use, and every sample's garments are draped on their pool bodies there:
a step costs the network and the physics, not a BVH build and a search for the doubtful faces
per sampled body.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from physdrape.garments.split import SPLIT_FORMAT, load_or_generate
from physdrape.model import DrapeInput
from physdrape.model.config import ModelConfig
from physdrape.physics import Material
from physdrape.pipeline import DrapePipeline, PosedBodies, Template
from physdrape.train.instances import InstanceCache, InstanceCacheError, part_pool
from physdrape.train.materials import draw_material
from physdrape.user_cache import cache_root


@dataclass(frozen=True)
class TrainingBatch:
    """A batch of training samples: the model's input and, from an instance cache, the physics
    teacher's drape of every vertex [m] (ΣV, 3) and each garment's instance index in the cache's
    training part (None without a cache)."""

    drape: DrapeInput
    teacher: torch.Tensor | None = None
    instances: tuple[int, ...] | None = None


def held_per_instance(held: dict[int, torch.Tensor], sample: TrainingBatch,
                      make: Callable[[], torch.Tensor]) -> torch.Tensor:
    """A per-vertex quantity of a sample drawn from the instance cache (ΣV, ...), held per instance
    in `held` (by `TrainingBatch.instances`): where any of the sample's instances is not held yet,
    make() computes it on the sample's whole batch and each instance keeps its garment's rows;
    returned as the held rows in the sample's order."""
    if any(k not in held for k in sample.instances):
        offsets = sample.drape.garments.vert_offsets.tolist()
        values = make()
        for g, key in enumerate(sample.instances):
            held.setdefault(key, values[offsets[g]:offsets[g + 1]].clone())
    return torch.cat([held[key] for key in sample.instances])


def default_split_dir(seed: int = 0) -> Path:
    """Where the generated garment split is cached: ~/.cache/physdrape/garment_split_seed<seed>_v<format>."""
    version = SPLIT_FORMAT.rsplit("/", 1)[-1]
    return cache_root() / f"garment_split_seed{seed}_v{version}"


@dataclass(frozen=True)
class DataConfig:
    """split_dir: garment split ("" = the default cache; garments are generated on first use, only
    those read); split_seed: its seed; subset: "train" or "test"; max_garments: use the first N
    (0 = all); body_pool_size: posed bodies precomputed; body_seed: seed of their shapes and
    poses; materials: "sampled" (HOOD's ranges) or "default"; dtype: of garments and bodies
    ("float32"/"float64").

    instances: folder of cached instances ("" = none: samples are built on the fly; see
    `physdrape.train.instances`), built on first use with `instance_count` training and
    `validation_count` validation instances; validation_garments: the last garments of the subset
    held out for validation; teacher_steps: two-level solver steps of each instance's teacher drape.

    outfits: the split's first N procedural outfits (a top over trousers, `garments.outfits`)
    trained on beside the subset's garments (0: none), worn as a Draper wears them (waistband
    gripped, pieces in layer order: `DrapePipeline.worn_job`); they are never held out.
    """

    split_dir: str = ""
    split_seed: int = 0
    subset: str = "train"
    max_garments: int = 0
    body_pool_size: int = 128
    body_seed: int = 0
    materials: str = "sampled"
    dtype: str = "float32"
    instances: str = ""
    instance_count: int = 512
    validation_count: int = 8
    validation_garments: int = 16
    teacher_steps: int = 100
    outfits: int = 0

    def __post_init__(self) -> None:
        if self.materials not in ("sampled", "default"):
            raise ValueError(f"DataConfig.materials must be 'sampled' or 'default', got {self.materials!r}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"DataConfig.dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.outfits < 0:
            raise ValueError(f"DataConfig.outfits must be ≥ 0 (0 = none), got {self.outfits}")
        if self.max_garments < 0:
            raise ValueError(f"DataConfig.max_garments must be ≥ 0 (0 = the whole subset), got {self.max_garments}")
        if self.body_pool_size < 1:
            raise ValueError("DataConfig.body_pool_size must be ≥ 1")
        if self.instance_count < 1 or self.validation_count < 0 or self.validation_garments < 0 or self.teacher_steps < 1:
            raise ValueError("DataConfig needs instance_count ≥ 1, validation_count ≥ 0, validation_garments ≥ 0 "
                             "and teacher_steps ≥ 1")


def load_templates(config: DataConfig, *, workers: int | None = None) -> list[Template]:
    """The first `max_garments` garments of the split's `subset` (0: all of it) as templates, with
    the split's first `outfits` outfits placed before the subset's last `validation_garments` (the
    held-out garments stay last).

    Only those garments are generated when missing (in `workers` processes, default one per CPU;
    an interrupted generation resumes), so a small `max_garments` starts in seconds.
    """
    split_dir = Path(config.split_dir).expanduser() if config.split_dir else default_split_dir(config.split_seed)
    raw = load_or_generate(split_dir, config.subset, count=config.max_garments or None, seed=config.split_seed,
                           workers=workers)
    if config.outfits:
        held = min(config.validation_garments, len(raw))
        outfits = load_or_generate(split_dir, "outfits", count=config.outfits, seed=config.split_seed,
                                   workers=workers)
        raw = raw[:len(raw) - held] + outfits + raw[len(raw) - held:]
    return [Template.from_mesh(g.verts, g.faces, name=g.name) for g in raw]


class DrapeSource:
    """`SampleSource` of the real pipeline (see the module docstring).

    model: the config of the model being trained; with an instance cache, its contact term is the
    teacher's (`physdrape.train.instances.teacher_solver`).
    """

    def __init__(self, config: DataConfig = DataConfig(), *, model: ModelConfig = ModelConfig(), body=None,
                 templates: list[Template] | None = None, log=sys.stderr) -> None:
        from physdrape.body.anny_body import get_anny_body

        self.config = config
        self.dtype = getattr(torch, config.dtype)
        self.body = body if body is not None else get_anny_body()
        self.templates = templates if templates is not None else load_templates(config)
        if not self.templates:
            raise ValueError("no garment templates to train on: check DataConfig.split_dir / subset / max_garments")
        self.pool = part_pool(self.body, config, "train")
        # every garment's rest state kept: each step draws instances of any of them
        self.pipeline = DrapePipeline(self.body, dtype=self.dtype, templates_kept=len(self.templates))
        self._posed: PosedBodies | None = None
        self.cache = self.validation_pool = None
        if config.instances:
            self.cache = InstanceCache(config.instances, config, model)
            self.validation_pool = part_pool(self.body, config, "val")
            self.cache.build(self.templates, self.body, {"train": self.pool, "val": self.validation_pool},
                             {"train": config.instance_count, "val": config.validation_count}, log=log)
            self._train = self.cache.part("train")[:config.instance_count]
            self._tensors = [self.cache.tensors("train", i) for i in range(len(self._train))]
            for inst, (x_init, _) in zip(self._train, self._tensors):
                template = self.templates[inst.garment] if inst.garment < len(self.templates) else None
                if template is None or template.name != inst.name or template.num_verts != x_init.shape[0]:
                    raise InstanceCacheError(
                        f"the instance cache {config.instances} holds garment {inst.name} (index {inst.garment}, "
                        f"{x_init.shape[0]} vertices), which this run's split does not have at that index: the "
                        "cache was made from another garment split; delete the folder to rebuild it")

    def make_batch(self, seeds: list[int]) -> TrainingBatch:
        """The samples of `seeds`: each seed draws a cached instance, or else a training garment,
        a pool body and a material; draped on the pool's bodies (`posed_pool`)."""
        if self.cache is not None:
            picks = [int(np.random.default_rng(seed).integers(len(self._train))) for seed in seeds]
            jobs = [self.pipeline.worn_job(self.templates[self._train[i].garment], self._train[i].body,
                                           Material(**self._train[i].material), self._tensors[i][0]) for i in picks]
            drape = self.pipeline.build(jobs, self.posed_pool())
            return TrainingBatch(drape, torch.cat([self._tensors[i][1] for i in picks]).to(self.dtype), tuple(picks))
        jobs = []
        for seed in seeds:
            rng = np.random.default_rng(seed)
            g = int(rng.integers(len(self.templates)))
            body = int(rng.integers(len(self.pool)))
            jobs.append(self.pipeline.worn_job(self.templates[g], body, draw_material(rng, self.config.materials)))
        return TrainingBatch(self.pipeline.build(jobs, self.posed_pool()))

    def posed_pool(self) -> PosedBodies:
        """The training pool's bodies as one posed batch, its surface (a BVH per body) and their
        doubtful faces built on the first call: what every sample is draped on."""
        if self._posed is None:
            self._posed = PosedBodies(self.pool.state(list(range(len(self.pool)))))
            self._posed.surface(self.dtype, self.pipeline.device).doubtful_faces()
        return self._posed

    def validation(self) -> list[TrainingBatch]:
        """The cache's validation instances, one batch each (empty without a cache)."""
        if self.cache is None:
            return []
        instances = self.cache.part("val")[:self.config.validation_count]
        out = []
        for i, inst in enumerate(instances):
            x_init, teacher = self.cache.tensors("val", i)
            job = self.pipeline.worn_job(self.templates[inst.garment], 0, Material(**inst.material), x_init)
            out.append(TrainingBatch(self.pipeline.build([job], self.validation_pool.state(inst.body)), teacher.to(self.dtype)))
        return out
