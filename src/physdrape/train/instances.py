"""Cached training instances: X_init and the physics teacher's drape, written once per instance.

With a cache a training step costs the network and the physics only, not the data pipeline
(skinning-transfer fits, X_init's strain limiting), and each instance carries a target made from
physics alone: the teacher drape, the two-level stretching solver (the product's physics, without
the network) run `DataConfig.teacher_steps` steps from the instance's X_init. The method stays
self-supervised: no external data, only our own solver run for longer than a drape can afford.

An instance is a training garment of the split on a body of the data's pool in a material, drawn
from the seed (`DataConfig.body_seed`, part, index), so instance i does not depend on how many
are cached and a larger `instance_count` extends a cache. Two parts:

- ``train``: garments of the subset except its last `validation_garments`, bodies of the pool;
- ``val``: those held-out garments, on bodies of their own (seed `body_seed` + 1), a fixed
  validation set whose learning curve the trainer logs (`physdrape.train.validation`).

Folder layout: ``manifest.json`` (what was cached: the data and teacher settings, and per
instance its garment, body, material and teacher energy) and ``<part>/<index>.safetensors``
(x_init and teacher [m], float32 or the data's dtype). Every file is written atomically and the
manifest after its instance files, so an interrupted build resumes where it stopped.
"""

from __future__ import annotations

import fcntl
import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save

from physdrape.atomic import write_bytes, write_text
from physdrape.body.pool import BodyPool
from physdrape.model.config import ModelConfig
from physdrape.model.stretching_solver import SolverKind, StretchingSolver
from physdrape.physics.energy import total_energy
from physdrape.pipeline import DrapePipeline, Job, Template
from physdrape.train.materials import draw_material

FORMAT = "physdrape-instances/1"
PARTS = ("train", "val")


class InstanceCacheError(ValueError):
    """A cache folder that does not fit the run (other settings, damaged files)."""


@dataclass(frozen=True)
class Instance:
    """One cached instance: `garment` (index into the subset's templates, and its name) on `body`
    (index into the part's body pool) in `material`; teacher_energy: E_total of the teacher drape [J]."""

    garment: int
    name: str
    body: int
    material: dict
    teacher_energy: float


def part_pool(body, data, part: str) -> BodyPool:
    """The posed bodies of a part: `body_pool_size` bodies of seed `body_seed` (train) or
    `body_seed` + 1 (val)."""
    return BodyPool(body, data.body_pool_size, seed=data.body_seed + PARTS.index(part), dtype=getattr(torch, data.dtype))


def teacher_solver(model: ModelConfig) -> StretchingSolver:
    """The teacher: the two-level solver with the product's settings (`ModelConfig()`), and the
    contact term (k_c, ε) of the model being trained, so the teacher and the loss share one energy."""
    shipped = ModelConfig()
    return StretchingSolver(kind=SolverKind.TWO_LEVEL, eta=shipped.eta, gamma=shipped.gamma,
                            max_step=shipped.max_step, margin=model.margin, contact_stiffness=model.contact_stiffness,
                            requery_every=shipped.requery_every, coarse_levels=shipped.coarse_levels,
                            coarse_smoothing=shipped.coarse_smoothing)


def _definition(data, model: ModelConfig) -> dict:
    """Everything the cached instances depend on (a cache made with other values is refused)."""
    keys = ("split_dir", "split_seed", "subset", "max_garments", "body_pool_size", "body_seed", "materials", "dtype",
            "validation_garments", "teacher_steps")
    return {"data": {k: getattr(data, k) for k in keys},
            "contact": {"stiffness": model.contact_stiffness, "margin": model.margin}}


class InstanceCache:
    """The cache folder of `data.instances` for a run's data and model config.

    Call `build` to write the missing instances (resumable), then `part(name)` for the instances
    and `tensors(name, i)` for one instance's (x_init, teacher).
    """

    def __init__(self, directory: str | Path, data, model: ModelConfig) -> None:
        self.directory = Path(directory).expanduser()
        self.data, self.model = data, model
        self.definition = _definition(data, model)
        self.manifest = {"format": FORMAT, **self.definition, "parts": {p: [] for p in PARTS}}
        path = self.directory / "manifest.json"
        if path.is_file():
            try:
                found = json.loads(path.read_text())
            except (OSError, json.JSONDecodeError) as exc:
                raise InstanceCacheError(f"{path} cannot be read ({exc}); delete the folder {self.directory} and "
                                         "run again to rebuild it") from exc
            mine = {k: self.manifest[k] for k in ("format", "data", "contact")}
            theirs = {k: found.get(k) for k in ("format", "data", "contact")}
            if mine != theirs:
                raise InstanceCacheError(
                    f"the instance cache {self.directory} was made with other settings ({theirs}) than this run "
                    f"({mine}); set data.instances to another folder, or delete that one to rebuild it")
            self.manifest = found

    def part(self, name: str) -> list[Instance]:
        return [Instance(**record) for record in self.manifest["parts"][name]]

    def tensors(self, name: str, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(x_init, teacher) of instance `index` of part `name`, each (V, 3) [m]."""
        path = self.directory / name / f"{index:06d}.safetensors"
        try:
            found = load_file(str(path))
            return found["x_init"], found["teacher"]
        except Exception as exc:
            raise InstanceCacheError(f"{path} cannot be read ({type(exc).__name__}: {exc}); delete it and run "
                                     "again: the missing instances are rebuilt") from exc

    def build(self, templates: list[Template], body, pools: dict[str, BodyPool], counts: dict[str, int], *,
              log=sys.stderr) -> None:
        """Write the instances of each part up to `counts[part]` that are not cached yet.

        templates: the subset's garments (the last `validation_garments` are held out for ``val``);
        body: the body model; pools: each part's posed bodies (`part_pool`).
        """
        held_out = self.data.validation_garments
        if not 0 < held_out < len(templates):
            raise InstanceCacheError(
                f"data.validation_garments is {held_out} but the training subset has {len(templates)} garments: "
                "it must hold out at least one garment and leave at least one to train on")
        if all(counts[p] <= len(self.manifest["parts"][p]) for p in PARTS):
            return
        self.directory.mkdir(parents=True, exist_ok=True)
        with open(self.directory / ".lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # another run building the same cache waits, then reads its work
            path = self.directory / "manifest.json"
            if path.is_file():
                self.manifest = json.loads(path.read_text())
            self._build(templates, body, pools, counts, log)

    def _build(self, templates: list[Template], body, pools: dict[str, BodyPool], counts: dict[str, int], log) -> None:
        held_out = self.data.validation_garments
        dtype = getattr(torch, self.data.dtype)
        pipeline = DrapePipeline(body, dtype=dtype)
        solver = teacher_solver(self.model)
        garments = {"train": list(range(len(templates) - held_out)),
                    "val": list(range(len(templates) - held_out, len(templates)))}
        started = time.perf_counter()
        for p in PARTS:
            pool = pools[p]
            records = self.manifest["parts"][p]
            for i in range(len(records), counts[p]):
                rng = np.random.default_rng([self.data.body_seed, PARTS.index(p), i])
                g = garments[p][int(rng.integers(len(garments[p])))]
                b = int(rng.integers(len(pool)))
                material = draw_material(rng, self.data.materials)
                state = pool.state(b)
                drape = pipeline.build([Job(templates[g], 0, material)], state)
                with torch.no_grad():
                    teacher = solver(drape.x_init, drape.cloth, f_hat=None, steps=self.data.teacher_steps,
                                     bodies=drape.bodies, body_index=drape.body_index)
                write_bytes(self.directory / p / f"{i:06d}.safetensors",
                            save({"x_init": drape.x_init.contiguous(), "teacher": teacher.contiguous()}))
                energy = float(total_energy(teacher, drape.cloth, drape.bodies, drape.body_index,
                                            contact_stiffness=self.model.contact_stiffness, margin=self.model.margin)[0])
                records.append(asdict(Instance(g, templates[g].name, b, asdict(material), energy)))
                write_text(self.directory / "manifest.json", json.dumps(self.manifest, indent=1))
                done = sum(len(self.manifest["parts"][q]) for q in PARTS)
                total = sum(max(counts[q], len(self.manifest["parts"][q])) for q in PARTS)
                print(f"[instances] {done}/{total} cached in {self.directory} ({time.perf_counter() - started:.0f} s)",
                      file=log, flush=True)
