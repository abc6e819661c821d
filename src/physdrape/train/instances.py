"""Cached training instances: X_init and the physics teacher's drape, written once per instance.

With a cache a training step costs the network and the physics only, not the data pipeline
(skinning-transfer fits, X_init's strain limiting), and each instance carries a target made from
physics alone: the teacher drape, the two-level stretching solver (the product's physics, without
the network, with the fixed `TEACHER_SETTINGS`) run `DataConfig.teacher_steps` steps from the
instance's X_init. The method stays
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
manifest after its instance files, so an interrupted build resumes where it stopped. The build
runs in `workers` processes (forked where the platform can, so the posed bodies are shared); an
instance does not depend on how many: each is drawn and draped from its own seed, and the
coordinating process writes them in order.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import multiprocessing as mp
import os
import signal
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save

from physdrape.atomic import write_bytes, write_text
from physdrape.body.pool import BodyPool
from physdrape.body.skinning_transfer import LIMIT_FIELDS, SkinningTransfer
from physdrape.model.config import ModelConfig
from physdrape.model.stretching_solver import SolverKind, StretchingSolver
from physdrape.physics.energy import total_energy
from physdrape.pipeline import DrapePipeline, Template
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


#: The teacher's solver settings (the two-level solver's, apart from the contact term): fixed
#: here, not taken from `ModelConfig`'s defaults, so that a cache's teacher drapes stay the
#: reference they were made as when the product's solver settings change. Recorded in the
#: manifest; a manifest without them was written with these.
TEACHER_SETTINGS = {"eta": 1.0, "gamma": 0.98, "max_step": 0.01, "requery_every": 3, "refactor_every": 3,
                    "coarse_levels": 2, "coarse_smoothing": 2}


def teacher_solver(model: ModelConfig) -> StretchingSolver:
    """The teacher: the two-level solver with `TEACHER_SETTINGS` and the contact term (k_c, ε) of
    the model being trained, so the teacher and the loss share one energy."""
    return StretchingSolver(kind=SolverKind.TWO_LEVEL, margin=model.margin, contact_stiffness=model.contact_stiffness,
                            **TEACHER_SETTINGS)


#: X_init's strain-limiting settings (`SkinningTransfer`'s defaults, what `DrapePipeline` skins
#: with) that a cache's X_init were made with; a manifest without them was written with
#: `SKINNED_BEFORE_MIN_STRETCH` (compression left as skinned).
X_INIT_SETTINGS = {name: getattr(SkinningTransfer, name) for name in LIMIT_FIELDS}
SKINNED_BEFORE_MIN_STRETCH = {**X_INIT_SETTINGS, "min_stretch": None}


def _definition(data, model: ModelConfig) -> dict:
    """Everything the cached instances depend on (a cache made with other values is refused)."""
    keys = ("split_dir", "split_seed", "subset", "max_garments", "body_pool_size", "body_seed", "materials", "dtype",
            "validation_garments", "teacher_steps")
    found = {k: getattr(data, k) for k in keys}
    if getattr(data, "outfits", 0):  # a cache without outfits keeps the definition it was written with
        found["outfits"] = data.outfits
    return {"data": found,
            "contact": {"stiffness": model.contact_stiffness, "margin": model.margin}, "teacher": TEACHER_SETTINGS,
            "x_init": X_INIT_SETTINGS}


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
            mine = {k: self.manifest[k] for k in ("format", "data", "contact", "teacher", "x_init")}
            theirs = {k: found.get(k) for k in ("format", "data", "contact")} | {
                "teacher": found.get("teacher", TEACHER_SETTINGS),
                "x_init": found.get("x_init", SKINNED_BEFORE_MIN_STRETCH)}
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
              log=sys.stderr, workers: int | None = None) -> None:
        """Write the instances of each part up to `counts[part]` that are not cached yet.

        templates: the subset's garments (the last `validation_garments` are held out for ``val``);
        body: the body model; pools: each part's posed bodies (`part_pool`); workers: processes
        (default: the machine's CPU count; the instances do not depend on it).
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
            todo = [(p, i) for p in PARTS for i in range(len(self.manifest["parts"][p]), counts[p])]
            if todo:
                workers = max(1, min(len(todo), (os.cpu_count() or 1) if workers is None else workers))
                maker = _InstanceMaker(templates, pools, DrapePipeline(body, dtype=getattr(torch, self.data.dtype)),
                                       teacher_solver(self.model), self.data, self.model)
                self._write(todo, maker, counts, workers, log)

    def _write(self, todo: list[tuple[str, int]], maker: _InstanceMaker, counts: dict[str, int], workers: int,
               log) -> None:
        """Make the instances `todo` in `workers` processes and write them in order, each
        instance's file before the manifest that records it."""
        started = time.perf_counter()
        total = sum(max(counts[q], len(self.manifest["parts"][q])) for q in PARTS)
        with _runner(maker, workers) as run:
            for (p, i), (record, x_init, teacher) in zip(todo, run(todo)):
                write_bytes(self.directory / p / f"{i:06d}.safetensors", save({"x_init": x_init, "teacher": teacher}))
                self.manifest["parts"][p].append(record)  # instance i: the todo list is in order
                write_text(self.directory / "manifest.json", json.dumps(self.manifest, indent=1))
                done = sum(len(self.manifest["parts"][q]) for q in PARTS)
                print(f"[instances] {done}/{total} cached in {self.directory} ({time.perf_counter() - started:.0f} s, "
                      f"{workers} process{'es' if workers > 1 else ''})", file=log, flush=True)


class _InstanceMaker:
    """Draws and drapes instance i of a part from its own seed: (record, x_init, teacher)."""

    def __init__(self, templates: list[Template], pools: dict[str, BodyPool], pipeline: DrapePipeline,
                 solver: StretchingSolver, data, model: ModelConfig) -> None:
        self.templates, self.pools, self.pipeline, self.solver = templates, pools, pipeline, solver
        self.data, self.model = data, model
        held_out = data.validation_garments
        self.garments = {"train": list(range(len(templates) - held_out)),
                         "val": list(range(len(templates) - held_out, len(templates)))}

    def __call__(self, job: tuple[str, int]) -> tuple[dict, torch.Tensor, torch.Tensor]:
        p, i = job
        rng = np.random.default_rng([self.data.body_seed, PARTS.index(p), i])
        g = self.garments[p][int(rng.integers(len(self.garments[p])))]
        b = int(rng.integers(len(self.pools[p])))
        material = draw_material(rng, self.data.materials)
        drape = self.pipeline.build([self.pipeline.worn_job(self.templates[g], 0, material)], self.pools[p].state(b))
        with torch.no_grad():
            teacher = self.solver(drape.x_init, drape.cloth, f_hat=None, steps=self.data.teacher_steps,
                                  bodies=drape.bodies, body_index=drape.body_index)
        energy = float(total_energy(teacher, drape.cloth, drape.bodies, drape.body_index,
                                    contact_stiffness=self.model.contact_stiffness, margin=self.model.margin)[0])
        record = asdict(Instance(g, self.templates[g].name, b, asdict(material), energy))
        return record, drape.x_init.contiguous(), teacher.contiguous()


_MAKER: _InstanceMaker | None = None  # the forked workers' maker, set before the pool starts


def _make_in_worker(job: tuple[str, int]) -> tuple[dict, torch.Tensor, torch.Tensor]:
    return _MAKER(job)


def _start_worker(maker: _InstanceMaker | None) -> None:
    """Pool workers leave Ctrl-C to the parent (which keeps what was written) and run one thread."""
    global _MAKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)
    if maker is not None:  # spawned: the maker arrives pickled
        _MAKER = maker


@contextlib.contextmanager
def _runner(maker: _InstanceMaker, workers: int) -> Iterator:
    """A map of `maker` over jobs yielding results in order: in this process, or in a pool of
    `workers` processes, forked where the platform can (the bodies and templates are shared)."""
    global _MAKER
    if workers <= 1:
        yield lambda jobs: map(maker, jobs)
        return
    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    _MAKER = maker
    try:
        with mp.get_context(method).Pool(workers, initializer=_start_worker,
                                         initargs=(None if method == "fork" else maker,)) as pool:
            yield lambda jobs: pool.imap(_make_in_worker, jobs)
    finally:
        _MAKER = None
