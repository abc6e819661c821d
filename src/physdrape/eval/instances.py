"""The evaluation's instances: which garment on which body, each built on demand.

Layout of a set of G garments: instance i drapes garment g = i mod G in pose k = i div G (every
garment once before any garment twice), on the body drawn from its own seed
``body_seed(seed, set, g, k)`` (`BodyPool.from_seeds`: one Anny shape and one pose, posed alone),
in the default material. Instance i (its garment and its body) is therefore the same whatever the
number of instances N, which takes the first N of this one list: by default N = G × poses per
garment (the whole test split, every garment `EvalConfig.poses_per_garment` times). The CC0
MakeHuman garments form a second set laid out the same way (`EvalConfig.makehuman_instances` poses
each), g being the garment's place among the .mhclo files found, so that skipping one garment
does not move the others' bodies; they are loaded and worn as `Draper.drape` loads and wears an
.mhclo by default (`instance_batch`'s `worn`).
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from physdrape.api.wear import Wear, Wearing
from physdrape.body.pool import BodyPool
from physdrape.body.skinning_transfer import LOCAL_STRETCH_BOUND
from physdrape.eval.config import EvalConfig
from physdrape.garments.generator import GarmentCategory
from physdrape.garments.split import DEFAULT_SIZES, read_manifest
from physdrape.model import DrapeInput
from physdrape.physics import Material
from physdrape.pipeline import POSE_DTYPE, DrapePipeline, Job, PosedBodies, Template
from physdrape.train.data import DataConfig, default_split_dir, load_templates

__all__ = ["Instance", "InstanceInput", "body_seed", "garment_category", "layout", "makehuman_instances",
           "split_instances"]

#: The categories a garment name can carry (the split's ``NNNN_<category>``), in table order.
CATEGORIES = tuple(c.value for c in GarmentCategory)


def body_seed(seed: int, set_name: str, garment: int, pose: int) -> int:
    """The seed of the body of garment `garment` in pose `pose` of set `set_name`: a function of
    these four alone (the set name enters as its CRC-32)."""
    entropy = [int(seed), zlib.crc32(set_name.encode("utf-8")), int(garment), int(pose)]
    return int(np.random.SeedSequence(entropy).generate_state(1)[0])


def layout(num_garments: int, count: int) -> list[tuple[int, int]]:
    """(garment, pose) of instances 0 … count − 1 of a set of `num_garments` garments."""
    return [(i % num_garments, i // num_garments) for i in range(count)]


def garment_category(name: str) -> str | None:
    """The category a split garment's name carries (``0007_croptop`` → ``croptop``); None for
    other names (the MakeHuman garments)."""
    number, sep, category = name.partition("_")
    return category if sep and number.isdigit() and category in CATEGORIES else None


class InstanceInput(NamedTuple):
    """One built instance. drape: the model's input (X_init included); init_s: wall seconds of
    building it, as `Draper.drape`'s init phase (the body surface and what the drape's queries
    need of it, X_init: skinning + contact-aware strain limiting, the packed batch; the transfer
    weights are fitted once per garment, outside the timing); skinned: where the classical references (the
    oracle, the VBD bench) start: the garment skinned with only the local strain limit of the
    skinning artefacts (`LOCAL_STRETCH_BOUND`), i.e. without the global pull-back that is part of
    PhysDrape's own pipeline and timed as such; None = start from X_init."""

    drape: DrapeInput
    init_s: float
    skinned: torch.Tensor | None


@dataclass
class Instance:
    """One instance of a set: garment `garment` (its place `garment_index` in the set) in pose
    `pose_index`, on body `body_index` of the set's pool, drawn from `body_seed`. Its tensors
    (`batch`) are built on demand and dropped after use, so the evaluation holds one instance in
    memory at a time."""

    set_name: str
    index: int
    garment: str
    garment_index: int
    body_index: int
    num_verts: int
    build: Callable[[], InstanceInput]
    pose_index: int = 0
    body_seed: int | None = None

    @property
    def category(self) -> str | None:
        return garment_category(self.garment)

    def batch(self) -> InstanceInput:
        return self.build()

    def describe(self) -> dict:
        """The instance as JSON-ready fields (eval.json's ``instances``)."""
        return {"index": self.index, "garment": self.garment, "garment_index": self.garment_index,
                "pose_index": self.pose_index, "category": self.category, "body_index": self.body_index,
                "body_seed": self.body_seed, "num_verts": self.num_verts}


def instance_batch(pipeline: DrapePipeline, pool: BodyPool, template: Template, body: int, *,
                   worn: bool = False) -> InstanceInput:
    """`template` on pool body `body`, default material, built by the drape pipeline exactly as
    `Draper.drape` builds it (see `InstanceInput`). `worn`: as `Draper.drape` wears a garment by
    default (`api.wear`): sized to fit where the garment has a sizing (an .mhclo: by its body
    binding), its waistband gripped, its closures stitched and its pieces kept in their layer
    order; the drape's cloth then carries those terms, so the oracle minimises the same energy.
    The skinned start is skinned from the same rest shape."""
    posed = PosedBodies(pool.state(body))
    pipeline.transfer(template)  # fitted once per garment, outside the timing
    job = Job(template, 0, Material())
    if worn:
        wear = Wear.check(sizing=None, grip=None, closures=None, layers=None, templates=[template])  # the defaults
        job = Wearing().job(template, 0, Material(), None, wear, posed.state, pool.shapes[body:body + 1], pipeline)
    t0 = time.perf_counter()
    drape = pipeline.build([job], posed)
    init_s = time.perf_counter() - t0
    with torch.no_grad():
        rest = None if job.rest is None else torch.as_tensor(job.rest, dtype=posed.state.rest_verts.dtype)
        skinned = replace(pipeline.transfer(template), max_stretch=LOCAL_STRETCH_BOUND).apply(posed.state,
                                                                                              rest_verts=rest)[0]
    return InstanceInput(drape, init_s, skinned.to(pipeline.dtype))


def build_instances(set_name: str, templates: Sequence[Template], *, num_garments: int, count: int,
                    config: EvalConfig, body, keys: Sequence[int] | None = None, worn: bool = False) -> list[Instance]:
    """The first `count` instances of a set of `num_garments` garments (see the module docstring).

    Args:
        templates: the set's first garments, at least min(num_garments, count) of them.
        keys: the number each garment's bodies are seeded with (default: its place in the set).
        worn: wear the garments as `Draper.drape` does by default (`instance_batch`).
    """
    grid = layout(num_garments, count)
    needed = min(num_garments, count)
    if len(templates) < needed:
        raise ValueError(f"{set_name}: {count} instances of {num_garments} garments need the first {needed} "
                         f"garments, got {len(templates)}")
    keys = list(range(num_garments)) if keys is None else list(keys)
    seeds = [body_seed(config.seed, set_name, keys[g], k) for g, k in grid]
    pool = BodyPool.from_seeds(body, seeds, dtype=POSE_DTYPE)
    pipeline = DrapePipeline(body, dtype=getattr(torch, config.dtype))
    return [Instance(set_name, i, templates[g].name, g, i, templates[g].num_verts,
                     partial(instance_batch, pipeline, pool, templates[g], i, worn=worn), pose_index=k,
                     body_seed=seeds[i])
            for i, (g, k) in enumerate(grid)]


def split_instances(config: EvalConfig, body) -> list[Instance]:
    """The test set: the split's test garments (its first `max_garments`, 0: all), the first
    `config.instances` instances of their layout (None: every garment `poses_per_garment` times).
    Only the garments those instances use are read (and generated when missing)."""
    split_dir = Path(config.split_dir).expanduser() if config.split_dir else default_split_dir(0)
    manifest = read_manifest(split_dir)
    size = int(manifest["num_test"]) if manifest is not None else DEFAULT_SIZES["test"]
    num_garments = min(config.max_garments, size) if config.max_garments else size
    if num_garments < 1:
        raise ValueError(f"no test garments in the split ({split_dir})")
    count = config.instances if config.instances is not None else num_garments * config.poses_per_garment
    data = DataConfig(split_dir=config.split_dir, split_seed=0, subset="test",
                      max_garments=min(num_garments, count))
    templates = load_templates(data)
    return build_instances("test", templates, num_garments=num_garments, count=count, config=config, body=body)


def makehuman_instances(config: EvalConfig, body) -> tuple[list[Instance], list[str]]:
    """Instances of the CC0 MakeHuman garments, `makehuman_instances` poses each, and notes on the
    garments skipped (missing, unreadable or over `makehuman_max_verts`)."""
    from physdrape.api.specs import garment_template
    from physdrape.api.types import DrapeError

    notes = []
    root = Path(config.makehuman_dir).expanduser()
    files = sorted(root.glob("*/*.mhclo")) + sorted(root.glob("*.mhclo"))
    if not files:
        return [], [f"MakeHuman: no .mhclo under {root}; skipped"]
    templates, keys = [], []
    for key, path in enumerate(files):
        try:
            template = garment_template(str(path))  # as `Draper.drape` loads an .mhclo, with its sizing
        except (DrapeError, OSError, ValueError) as exc:
            notes.append(f"MakeHuman: {path.name} skipped ({type(exc).__name__}: {exc})")
            continue
        if config.makehuman_max_verts and template.num_verts > config.makehuman_max_verts:
            notes.append(f"MakeHuman: {path.name} skipped ({template.num_verts} vertices > makehuman_max_verts "
                         f"{config.makehuman_max_verts})")
            continue
        templates.append(template)
        keys.append(key)
    if not templates:
        return [], notes
    count = len(templates) * config.makehuman_instances
    return build_instances("makehuman", templates, num_garments=len(templates), count=count, config=config,
                           body=body, keys=keys, worn=True), notes
