"""The evaluation protocol (paper Tables 1–2, DESIGN.md Sec. 4–5): model rows vs. the physics oracle.

Instances: the test garments of the split × a seeded pool of posed Anny bodies (shapes and poses
drawn with the evaluation seed), default material. Instance i drapes garment ``garment_of(i)``
(evenly spaced over the test garments when there are fewer instances than garments, cyclic
otherwise) on pool body i. Every instance is draped alone (batch of one), so wall times are per
garment. Optionally the CC0 MakeHuman garments are evaluated the same way, as a second set.

Rows of Table 1, all from ONE checkpoint (the variant is an inference-time switch of the model):

- ``gnn_only``: X = X_init + Δx (variant GNN_ONLY: no solver, no handler);
- ``post_col``: GNN → stretching solver (T = eval_steps) → collision handler with δ = 1 applied
  as post-processing (variant POST_COL; the paper's Post-Col is a model *trained* without the
  handler — here it is the full model's weights with the learned δ replaced by 1);
- ``physdrape_t3`` / ``physdrape_t15``: the full model (GNN → solver T → handler, learned δ);
- ``physics_only``: the same solver and handler with the network left out (Δx = 0, f̂ = 0): what
  the network adds is the difference to ``physdrape_t15``;
- ``oracle``: `physdrape.physics.relax` from the skinned start (penalty contact, default tol 1e-2, a
  wall-time budget per instance); its row reports whether it converged;
- ``oracle_refined``: the same `relax` started from the PhysDrape (T=15) drape (the refinement mode
  users call to polish a drape); its wall time includes the model's;
- ``reference``: per instance the lower-E_total of the two oracle results: the best equilibrium
  found from either start. The oracle is a local minimiser, and from the skinned start it can
  settle in a higher-energy equilibrium than the one near the model's drape; the reference is
  what every ratio is measured against (without refinement: the oracle).

Table 2 (module ablation: GNN / +solver / +collision / full): from separately trained checkpoints
when given, otherwise the same switches of the main checkpoint (labelled as such).

Metrics per row and instance: `physdrape.physics.metrics.drape_metrics` (E_strain, E_bend, B2G %,
close %, residual force) plus the total static energy the oracle minimises (strain + bend +
gravity + contact penalty) and the wall time. Energies are also given as the ratio of the row's
mean to the reference's mean over the same instances.
"""

from __future__ import annotations

import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from physdrape.physics.metrics import drape_metrics
from physdrape.model import DrapeInput, ModelConfig, PhysDrape, Variant
from physdrape.physics import Cloth, Material
from physdrape.physics.forces import energy_terms
from physdrape.physics.oracle import penalty_contact_energy, silenced

__all__ = [
    "ABLATION_ROWS",
    "MAIN_ROWS",
    "PUBLISHED_ABLATION",
    "PUBLISHED_MAIN",
    "EvalConfig",
    "InstanceInput",
    "RowSpec",
    "evaluate",
    "load_model",
    "render_markdown",
    "write_results",
]

#: Context only: the paper's numbers (CLOTH3D garments, SMPL bodies) — different data from ours.
PUBLISHED_NOTE = "published, CLOTH3D/SMPL — different data"
PUBLISHED_MAIN = [
    {"method": "DeePSD", "strain": 7.22, "bend": 0.01, "b2g_percent": 7.2},
    {"method": "DIG", "strain": 6.32, "bend": 0.01, "b2g_percent": 1.8},
    {"method": "DrapeNet", "strain": 0.43, "bend": 0.01, "b2g_percent": 0.9},
    {"method": "PhysDrape (T=3)", "strain": 0.20, "bend": 0.004, "b2g_percent": 0.05},
    {"method": "PhysDrape (T=15)", "strain": 0.15, "bend": 0.004, "b2g_percent": 0.05},
]
PUBLISHED_ABLATION = [
    {"method": "GNN", "strain": 0.20, "bend": 0.004, "b2g_percent": 3.50},
    {"method": "GNN + solver", "strain": 0.17, "bend": 0.003, "b2g_percent": 2.29},
    {"method": "GNN + collision", "strain": 0.21, "bend": 0.004, "b2g_percent": 0.06},
    {"method": "GNN + solver + collision (full)", "strain": 0.15, "bend": 0.004, "b2g_percent": 0.05},
]

METRIC_KEYS = ("strain", "bend", "b2g_percent", "close_percent", "residual_force", "residual_relative", "energy_total")


@dataclass(frozen=True)
class RowSpec:
    """One model row: `variant` of the model, `steps` solver steps T (None: the checkpoint's
    eval_steps), `definition` a one-line statement of what ran; network=False runs the model's
    physics alone (`PhysDrape.physics_only`: Δx = 0, f̂ = 0)."""

    key: str
    label: str
    variant: Variant
    steps: int | None
    definition: str
    network: bool = True


MAIN_ROWS = (
    RowSpec("gnn_only", "GNN only", Variant.GNN_ONLY, None, "X_init + Δx of the GNN (no solver, no handler)"),
    RowSpec("post_col", "Post-Col", Variant.POST_COL, None,
            "GNN → solver (T = eval_steps) → handler with δ = 1 as post-processing (full model's weights, learned δ replaced by 1)"),
    RowSpec("physdrape_t3", "PhysDrape (T=3)", Variant.FULL, 3, "GNN → solver T = 3 → handler (learned δ)"),
    RowSpec("physdrape_t15", "PhysDrape (T=15)", Variant.FULL, 15, "GNN → solver T = 15 → handler (learned δ)"),
    RowSpec("physics_only", "No network (T=15; context)", Variant.FULL, 15,
            "X_init → solver T = 15 with Δx = 0, f̂ = 0 → handler: the model's physics without its network, "
            "so the PhysDrape row minus this one is what the network adds", network=False),
)
ABLATION_ROWS = (
    RowSpec("gnn", "GNN", Variant.GNN_ONLY, None, "GNN only"),
    RowSpec("gnn+solver", "GNN + solver", Variant.GNN_SOLVER, None, "GNN → solver (T = eval_steps)"),
    RowSpec("gnn+collision", "GNN + collision", Variant.GNN_COLLISION, None, "GNN → handler"),
    RowSpec("full", "GNN + solver + collision (full)", Variant.FULL, None, "GNN → solver (T = eval_steps) → handler"),
)
ABLATION_NAMES = tuple(r.key for r in ABLATION_ROWS)


@dataclass(frozen=True)
class EvalConfig:
    """instances: test instances N; seed: of the body shapes/poses (and instance layout);
    oracle: run the oracle; oracle_budget_s: its wall-time budget per instance [s]; oracle_tol:
    its residual tolerance; oracle_max_iters: its iteration cap; oracle_refine: also run the
    oracle from the PhysDrape (T=15) drape and measure against the better of the two;
    split_dir / max_garments: the garment split ("" = default cache) and its first N test
    garments (0 = all); makehuman_dir: CC0 MakeHuman garments (.mhclo), "" = skip;
    makehuman_instances: bodies per MakeHuman garment; makehuman_max_verts: skip MakeHuman
    garments with more vertices (0 = no cap; the largest CC0 suit, 9.7k vertices, peaks at
    1.9 GiB with the oracle); dtype: of garments, bodies and physics ("float32"/"float64"; the
    network keeps its own); threads: torch threads (1 was fastest on the shared CPU)."""

    instances: int = 10
    seed: int = 0
    oracle: bool = True
    oracle_budget_s: float = 60.0
    oracle_tol: float = 1e-2
    oracle_max_iters: int = 200
    oracle_refine: bool = True
    split_dir: str = ""
    max_garments: int = 0
    makehuman_dir: str = ""
    makehuman_instances: int = 1
    makehuman_max_verts: int = 0
    dtype: str = "float64"
    threads: int = 1

    def __post_init__(self) -> None:
        if self.instances < 1:
            raise ValueError(f"EvalConfig.instances must be ≥ 1, got {self.instances}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"EvalConfig.dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.makehuman_max_verts < 0:
            raise ValueError(f"EvalConfig.makehuman_max_verts must be ≥ 0 (0: no cap), got {self.makehuman_max_verts}")
        if self.oracle_max_iters < 1:
            raise ValueError(f"EvalConfig.oracle_max_iters must be ≥ 1, got {self.oracle_max_iters}")
        if not self.oracle_budget_s > 0:
            raise ValueError(f"EvalConfig.oracle_budget_s must be > 0, got {self.oracle_budget_s}")


# ------------------------------------------------------------------------------------------
# Models and instances
# ------------------------------------------------------------------------------------------


def load_model(checkpoint: str | os.PathLike, *, variant: Variant | None = None) -> tuple[PhysDrape, dict]:
    """The model of a checkpoint (directory, or a run directory: its latest), switched to `variant`.

    Returns (model in eval mode, info {"path", "step", "variant", "eval_steps", "dtype"}).
    """
    from physdrape.config_io import from_mapping
    from physdrape.train.checkpoint import (
        CheckpointError,
        latest_checkpoint,
        read_checkpoint,
    )

    path = Path(checkpoint)
    if (path / "latest").is_file():
        path = latest_checkpoint(path)
    tensors, config = read_checkpoint(path)
    train = config.get("train", {})
    if "model" not in train:
        raise CheckpointError(f"{path}/config.json has no train.model section: not a PhysDrape training checkpoint")
    model_cfg = from_mapping(ModelConfig, train["model"], where=f"{path}/config.json:train.model")
    if variant is not None:
        model_cfg = replace(model_cfg, variant=variant)
    dtype = getattr(torch, train.get("dtype", "float32"))
    model = PhysDrape(model_cfg).to(dtype)
    model.load_state_dict(tensors)
    model.eval()
    step = path.name.split("-")[-1]
    info = {"path": str(path.resolve()), "step": int(step) if step.isdigit() else None, "variant": model_cfg.variant.value,
            "eval_steps": model_cfg.eval_steps, "dtype": str(dtype).removeprefix("torch.")}
    return model, info


def garment_of(i: int, num_instances: int, num_garments: int) -> int:
    """Garment of instance i: evenly spaced when N ≤ G, cyclic otherwise."""
    return (i * num_garments) // num_instances if num_instances <= num_garments else i % num_garments


@dataclass
class _Instance:
    """One test instance; its tensors (`batch`) are built on demand and dropped after use, so the
    evaluation holds one instance in memory at a time."""

    set_name: str
    index: int
    garment: str
    garment_index: int
    body_index: int
    num_verts: int
    build: Callable[[], InstanceInput]

    def batch(self) -> InstanceInput:
        return self.build()


class InstanceInput(NamedTuple):
    """One built instance. drape: the model's input (X_init included); init_s: wall seconds of
    computing that X_init (skinning + contact-aware strain limiting; the transfer weights are
    fitted once per garment, outside the timing); skinned: where the classical references (the
    oracle, the VBD bench) start: the garment skinned with only the local strain limit of the
    skinning artefacts (`LOCAL_STRETCH_BOUND`), i.e. without the global pull-back that is part of
    PhysDrape's own pipeline and timed as such; None = start from X_init."""

    drape: DrapeInput
    init_s: float
    skinned: torch.Tensor | None


def _instance_batch(source, garment: int, body: int) -> InstanceInput:
    """Garment `garment` of the source on pool body `body`, default material (see `InstanceInput`)."""
    from physdrape.body.skinning_transfer import LOCAL_STRETCH_BOUND
    from physdrape.geometry.garment import GarmentBatch
    from physdrape.geometry.proximity import BodySurface

    transfer, state = source.transfer(garment), source.pool.state(body)
    with torch.no_grad():
        t0 = time.perf_counter()
        x_init = transfer.apply(state)[0].to(source.dtype)
        init_s = time.perf_counter() - t0
        skinned = replace(transfer, max_stretch=LOCAL_STRETCH_BOUND).apply(state)[0].to(source.dtype)
    batch = GarmentBatch.pack([source.templates[garment]])
    bodies = BodySurface(source.pool.verts[body:body + 1], source.pool.faces)
    return InstanceInput(DrapeInput(batch, Cloth.build(batch, Material()), x_init, bodies, batch.vert_garment),
                         init_s, skinned)


def _test_instances(config: EvalConfig, body=None) -> tuple[list[_Instance], object]:
    from physdrape.train.data import DataConfig, DrapeSource

    data = DataConfig(split_dir=config.split_dir, subset="test", max_garments=config.max_garments,
                      body_pool_size=config.instances, body_seed=config.seed, materials="default", dtype=config.dtype)
    source = DrapeSource(data, body=body)
    out = []
    for i in range(config.instances):
        g = garment_of(i, config.instances, len(source.templates))
        out.append(_Instance("test", i, source.templates[g].name, g, i, source.templates[g].num_verts,
                             partial(_instance_batch, source, g, i)))
    return out, source


def _makehuman_instances(config: EvalConfig, body) -> tuple[list[_Instance], list[str]]:
    """Instances of the CC0 MakeHuman garments (skipped with a note if anything is missing)."""
    from physdrape.garments.mhclo import load_mhclo
    from physdrape.geometry.garment import Garment as GarmentMesh
    from physdrape.train.data import DataConfig, DrapeSource

    notes = []
    root = Path(config.makehuman_dir).expanduser()
    files = sorted(root.glob("*/*.mhclo")) + sorted(root.glob("*.mhclo"))
    if not files:
        return [], [f"MakeHuman: no .mhclo under {root}; skipped"]
    dtype = getattr(torch, config.dtype)
    templates = []
    for path in files:
        try:
            g = load_mhclo(path)
            if config.makehuman_max_verts and len(g.verts) > config.makehuman_max_verts:
                notes.append(f"MakeHuman: {path.name} skipped ({len(g.verts)} vertices > makehuman_max_verts "
                             f"{config.makehuman_max_verts})")
                continue
            templates.append(GarmentMesh.from_mesh(g.verts, g.faces, name=path.stem, dtype=dtype))
        except Exception as exc:  # noqa: BLE001 (an optional set: report and go on)
            notes.append(f"MakeHuman: {path.name} skipped ({type(exc).__name__}: {exc})")
    if not templates:
        return [], notes
    count = len(templates) * config.makehuman_instances
    data = DataConfig(subset="test", body_pool_size=count, body_seed=config.seed + 1, materials="default", dtype=config.dtype)
    source = DrapeSource(data, body=body, templates=templates)
    out = []
    for i in range(count):
        g = i % len(templates)
        out.append(_Instance("makehuman", i, templates[g].name, g, i, templates[g].num_verts,
                             partial(_instance_batch, source, g, i)))
    return out, notes


# ------------------------------------------------------------------------------------------
# Running rows
# ------------------------------------------------------------------------------------------


def _metrics(x: torch.Tensor, batch: DrapeInput) -> dict[str, float]:
    m = drape_metrics(x, batch.garments, batch.bodies, batch.body_index, cloth=batch.cloth)
    out = {name: float(getattr(m, name)[0]) for name in m.__dataclass_fields__}
    out["energy_total"] = float(total_energy(x, batch)[0])
    return out


@torch.no_grad()
def total_energy(x: torch.Tensor, batch: DrapeInput) -> torch.Tensor:
    """E_strain + E_bend + E_grav + E_contact per garment [J] (G,): what the oracle minimises
    (penalty contact at vertices and face centroids with its default stiffness and margin; the
    batch's materials)."""
    terms = energy_terms(x, batch.cloth)
    contact = penalty_contact_energy(x, batch.cloth, batch.bodies, batch.body_index)
    return terms["strain"] + terms["bend"] + terms["gravity"] + contact


@torch.no_grad()
def run_model(model: PhysDrape, batch: DrapeInput, *, steps: int | None, network: bool = True) -> tuple[torch.Tensor, float]:
    """(drape x, wall seconds) of one model call (network=False: `PhysDrape.physics_only`)."""
    t0 = time.perf_counter()
    out = model(batch, steps=steps) if network else model.physics_only(batch, steps=steps)
    return out.x, time.perf_counter() - t0


def run_oracle(batch: DrapeInput, config: EvalConfig, start: torch.Tensor | None = None):
    """`relax` from `start` (default X_init) on one instance (penalty contact), with the
    configured tol and budget."""
    from physdrape.physics.oracle import relax

    garment_of_vert = batch.garments.vert_garment
    body_of_garment = torch.zeros(batch.garments.num_garments, dtype=torch.int64).scatter_(0, garment_of_vert, batch.body_index)
    with silenced(1):
        return relax(batch.x_init if start is None else start, batch.cloth, batch.bodies, body_of_garment,
                     contact="penalty", tol=config.oracle_tol,
                     max_iters=config.oracle_max_iters, time_budget_s=config.oracle_budget_s)


def _oracle_record(result, batch: DrapeInput) -> dict:
    rec = _metrics(result.x.to(batch.x_init.dtype), batch)
    rec.update(wall_s=float(result.wall_time), converged=bool(result.converged), reason=result.reason,
               oracle_residual=float(result.residual.max()), iterations=len(result.history) - 1,
               oracle_energy_total=float(result.energy_terms["total"].sum()))
    rec["history"] = [{"iteration": h.iteration, "energy": h.energy, "residual": h.residual, "wall": h.wall}
                      for h in result.history]
    return rec


# ------------------------------------------------------------------------------------------
# Aggregation
# ------------------------------------------------------------------------------------------


def _summary(records: list[dict]) -> dict:
    out = {}
    for key in METRIC_KEYS + ("wall_s",):
        values = [r[key] for r in records]
        out[key] = float(np.mean(values)) if values else math.nan
    out["wall_s_median"] = float(np.median([r["wall_s"] for r in records])) if records else math.nan
    return out


def _with_ratios(summary: dict, reference: dict | None) -> dict:
    """Adds strain/bend ratio to the reference's mean over the same instances."""
    for key in ("strain", "bend"):
        ref = reference[key] if reference else math.nan
        summary[f"{key}_ratio"] = summary[key] / ref if reference and ref != 0 else math.nan
    return summary


def _oracle_summary(records: list[dict]) -> dict:
    summary = _summary(records)
    summary["converged"] = sum(r["converged"] for r in records)
    summary["oracle_residual_max"] = max(r["oracle_residual"] for r in records)
    return summary


def _reference(oracle: list[dict], refined: list[dict]) -> list[dict]:
    """Per instance the oracle result with the lower E_total (ties: the oracle's), tagged with
    its source ("oracle" or "oracle_refined"); without refinement, the oracle's own records."""
    if not refined:
        return [{**r, "source": "oracle"} for r in oracle]
    return [{**b, "source": "oracle_refined"} if b["energy_total"] < a["energy_total"] else {**a, "source": "oracle"}
            for a, b in zip(oracle, refined, strict=True)]


#: The model row the oracle refines (EvalConfig.oracle_refine).
REFINED_ROW = "physdrape_t15"


def _evaluate_set(instances: list[_Instance], models: dict, rows: dict, config: EvalConfig, log) -> dict:
    """Per-instance records and summaries of every row (and the oracle) on one instance set."""
    per_row: dict[str, list[dict]] = {key: [] for key in rows}
    oracle: list[dict] = []
    refined: list[dict] = []
    start: list[dict] = []
    plain: list[dict] = []
    refine = config.oracle and config.oracle_refine and REFINED_ROW in rows
    for inst in instances:
        batch, init_s, skinned = inst.batch()
        start.append({**_metrics(batch.x_init, batch), "wall_s": init_s})
        if skinned is not None:
            plain.append({**_metrics(skinned, batch), "wall_s": 0.0})
        to_refine = None
        for key, (model_key, steps, network) in rows.items():
            x, wall = run_model(models[model_key], batch, steps=steps, network=network)
            rec = _metrics(x, batch)
            rec["wall_s"] = init_s + wall  # a drape costs its kinematic init plus the model
            rec["model_wall_s"] = wall
            per_row[key].append(rec)
            if refine and key == REFINED_ROW:
                to_refine = x
        line = f"[eval] {inst.set_name} {inst.index + 1}/{len(instances)} {inst.garment} ({inst.num_verts} verts)"
        if config.oracle:
            oracle.append(_oracle_record(run_oracle(batch, config, skinned), batch))
            line += f": oracle {oracle[-1]['reason']} in {oracle[-1]['wall_s']:.1f} s"
        if refine:
            rec = _oracle_record(run_oracle(batch, config, to_refine), batch)
            rec["oracle_wall_s"] = rec["wall_s"]
            rec["wall_s"] += per_row[REFINED_ROW][-1]["wall_s"]  # the drape it polishes is part of its cost
            refined.append(rec)
            line += f"; refined {rec['reason']} in {rec['oracle_wall_s']:.1f} s"
        del batch
        log(f"{line}; peak memory {_peak_rss_gib():.1f} GiB")
    reference = _reference(oracle, refined) if oracle else []
    ref_summary = _oracle_summary(reference) if reference else None
    if ref_summary is not None:
        ref_summary["from_refinement"] = sum(r["source"] == "oracle_refined" for r in reference)
    result = {
        "instances": [{"index": i.index, "garment": i.garment, "garment_index": i.garment_index,
                       "body_index": i.body_index, "num_verts": i.num_verts} for i in instances],
        "rows": {key: {"summary": _with_ratios(_summary(recs), ref_summary), "per_instance": recs}
                 for key, recs in per_row.items()},
        "oracle": ({"summary": _with_ratios(_oracle_summary(oracle), ref_summary), "per_instance": oracle}
                   if oracle else None),
        "oracle_refined": ({"summary": _with_ratios(_oracle_summary(refined), ref_summary), "per_instance": refined}
                           if refined else None),
        "reference": ({"summary": _with_ratios(dict(ref_summary), ref_summary),
                       "per_instance": [{k: v for k, v in r.items() if k != "history"} for r in reference]}
                      if reference else None),
        "x_init": {"summary": _with_ratios(_summary(start), ref_summary), "per_instance": start},
    }
    if plain:
        result["skinned"] = {"summary": _with_ratios(_summary(plain), ref_summary), "per_instance": plain}
    return result


def _peak_rss_gib() -> float:
    """Peak resident memory of this process so far [GiB] (Linux: ru_maxrss in KiB)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def _versions() -> dict:
    import physdrape

    def git(*args: str) -> str | None:
        try:
            return subprocess.run(["git", *args], cwd=Path(__file__).parent, capture_output=True, check=False,
                                  text=True, timeout=5).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return None

    commit, status = git("rev-parse", "HEAD"), git("status", "--porcelain")
    return {"physdrape": physdrape.__version__, "torch": torch.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "git_commit": commit or None,
            "git_dirty": bool(status) if status is not None else None, "platform": platform.platform()}


def evaluate(checkpoint: str | os.PathLike, config: EvalConfig = EvalConfig(), *,
             ablation: dict[str, str | os.PathLike] | None = None, body=None, command: str | None = None,
             log=print) -> dict:
    """Run the protocol (see the module docstring); returns the JSON-ready results.

    Args:
        checkpoint: the main checkpoint (or a run directory: its latest).
        ablation: optional {name: checkpoint} with names among ABLATION_NAMES, each a model
            trained with that variant; names not given are switched on the main checkpoint.
        body: an `AnnyBody` (default: `get_anny_body()`).
        command: the command line to record.
    """
    ablation = dict(ablation or {})
    unknown = sorted(set(ablation) - set(ABLATION_NAMES))
    if unknown:
        raise ValueError(f"unknown ablation names {unknown}; use {list(ABLATION_NAMES)} (e.g. --ablation gnn=DIR)")
    if config.threads:
        torch.set_num_threads(config.threads)
    t_start = time.perf_counter()
    models, checkpoints = {}, {}
    for spec in MAIN_ROWS:
        models[spec.key], checkpoints[spec.key] = load_model(checkpoint, variant=spec.variant)
    eval_steps = checkpoints["physdrape_t15"]["eval_steps"]
    main_rows = {s.key: (s.key, s.steps if s.steps is not None else eval_steps, s.network) for s in MAIN_ROWS}
    ablation_sources = {}
    for spec in ABLATION_ROWS:
        key = f"ablation:{spec.key}"
        if spec.key in ablation:
            models[key], checkpoints[key] = load_model(ablation[spec.key], variant=spec.variant)
            ablation_sources[spec.key] = "retrained"
        else:
            models[key], checkpoints[key] = load_model(checkpoint, variant=spec.variant)
            ablation_sources[spec.key] = "switched"
    abl_rows = {f"ablation:{s.key}": (f"ablation:{s.key}", checkpoints[f"ablation:{s.key}"]["eval_steps"], True)
                for s in ABLATION_ROWS}

    if body is None:
        from physdrape.body.anny_body import get_anny_body

        body = get_anny_body()
    instances, _ = _test_instances(config, body=body)
    sets = {"test": _evaluate_set(instances, models, {**main_rows, **abl_rows}, config, log)}
    notes = []
    if config.makehuman_dir:
        try:
            mh, notes = _makehuman_instances(config, body)
        except Exception as exc:  # noqa: BLE001 (an optional set never sinks the main evaluation)
            mh, notes = [], [f"MakeHuman set skipped ({type(exc).__name__}: {exc})"]
        if mh:
            sets["makehuman"] = _evaluate_set(mh, models, {**main_rows, **abl_rows}, config, log)
        for note in notes:
            log(f"[eval] {note}")

    return {
        "format": "physdrape-eval-1",
        "config": asdict(config),
        "command": command if command is not None else " ".join(sys.argv),
        "versions": _versions(),
        "checkpoints": checkpoints,
        "row_definitions": {s.key: {"label": s.label, "variant": s.variant.value,
                                    "steps": main_rows[s.key][1] if s.variant.uses_solver else None,
                                    "definition": s.definition} for s in MAIN_ROWS},
        "ablation_definitions": {s.key: {"label": s.label, "variant": s.variant.value,
                                         "steps": abl_rows[f"ablation:{s.key}"][1] if s.variant.uses_solver else None,
                                         "definition": s.definition, "source": ablation_sources[s.key]}
                                 for s in ABLATION_ROWS},
        "oracle_definition": (f"physdrape.physics.relax from the skinned start (see Skinned), penalty contact at vertices and face centroids, tol {config.oracle_tol} "
                              f"(max over free vertices of |F|/(m g)), energy_tol 1e-6, budget {config.oracle_budget_s} s, "
                              f"max {config.oracle_max_iters} iterations, per instance"
                              + ("; the same from the PhysDrape (T=15) drape (refined); the reference is per instance "
                                 "the lower-E_total of the two" if config.oracle_refine else "")) if config.oracle else None,
        "published": {"note": PUBLISHED_NOTE, "table1": PUBLISHED_MAIN, "table2": PUBLISHED_ABLATION},
        "sets": sets,
        "notes": notes,
        "total_wall_s": time.perf_counter() - t_start,
    }


# ------------------------------------------------------------------------------------------
# Output
# ------------------------------------------------------------------------------------------


def _fmt(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        if value != 0 and (abs(value) < 10 ** -digits or abs(value) >= 1e4):
            return f"{value:.{digits - 1}e}"
        return f"{value:.{digits}g}" if abs(value) < 1 else f"{value:.{digits}f}".rstrip("0").rstrip(".")
    return str(value)


def _table(rows: list[tuple[str, dict]], *, timing: bool, oracle: bool) -> list[str]:
    head = ["Method", "E_strain [J]", "E_bend [J]", "B2G %", "close %", "residual [N]", "E_total [J]"]
    if oracle:
        head += ["E_strain / reference", "E_bend / reference"]
    if timing:
        head += ["wall / garment [s] (mean)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, s in rows:
        cells = [label] + [_fmt(s.get(k)) for k in ("strain", "bend", "b2g_percent", "close_percent", "residual_force", "energy_total")]
        if oracle:
            cells += [_fmt(s.get("strain_ratio")), _fmt(s.get("bend_ratio"))]
        if timing:
            cells += [_fmt(s.get("wall_s"))]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _published(rows: list[dict]) -> list[str]:
    lines = [f"| Method ({PUBLISHED_NOTE}) | E_strain | E_bend | B2G % |", "|---|---|---|---|"]
    lines += [f"| {r['method']} | {r['strain']} | {r['bend']} | {r['b2g_percent']} |" for r in rows]
    return lines


def render_markdown(results: dict, *, timing: bool = True) -> str:
    """Both tables (per instance set) as Markdown; timing=False leaves the wall-time columns out
    (everything else is deterministic for a seed)."""
    cfg = results["config"]
    has_oracle = bool(cfg["oracle"])
    out = ["# PhysDrape evaluation", ""]
    ck = results["checkpoints"]["physdrape_t15"]
    out.append(f"Checkpoint: `{ck['path']}` (step {ck['step']}). Seed {cfg['seed']}, {cfg['instances']} test instances, "
               f"default material, dtype {cfg['dtype']}.")
    if timing:
        out.append(f"Command: `{results['command']}`")
    out.append("")
    out.append("Rows (all from the one checkpoint, switched at inference):")
    for d in results["row_definitions"].values():
        out.append(f"- **{d['label']}**: {d['definition']}" + (f" (T = {d['steps']})" if d["steps"] else ""))
    out.append("- **X_init**: the kinematic initialisation every row starts from (skinning transfer, then contact-aware "
               "strain limiting of the edges to 1.02 x rest), for context. Every model row's wall time includes it.")
    out.append("- **Skinned**: the skinning transfer with only the local limit of its artefacts (edges ≤ 1.5 x rest): "
               "where the oracle starts (a classical solver gets the plain kinematic start, not PhysDrape's pull-back).")
    if has_oracle:
        out.append(f"- **Oracle**: {results['oracle_definition']}.")
    if cfg.get("oracle_refine") and has_oracle:
        out.append("- **Oracle refining PhysDrape (T=15)**: the oracle started from the model's drape (the refinement "
                   "mode); its wall time includes the model's. **Reference**: per instance the lower-E_total of the "
                   "two oracle results, the best equilibrium found from either start.")
    out.append("")
    out.append("Energies are means over instances under the default material; E_total = E_strain + E_bend + E_grav + "
               "contact penalty (what the oracle minimises). Ratios: row mean / reference mean on "
               "the same instances. residual: mean |F_int| over vertices > 3 mm from the body. The oracle's wall time "
               "is a lower bound where it stopped on its budget instead of converging.")
    for set_name, data in results["sets"].items():
        oracle = data["oracle"]["summary"] if data["oracle"] else None
        title = "test garments × seeded Anny shapes/poses" if set_name == "test" else "CC0 MakeHuman garments"
        out += ["", f"## Table 1 — {title} ({len(data['instances'])} instances)", ""]
        rows = [(results["row_definitions"][k]["label"], data["rows"][k]["summary"]) for k in results["row_definitions"]]
        if "x_init" in data:
            rows.insert(0, ("X_init (kinematic start, no model; context)", data["x_init"]["summary"]))
        if "skinned" in data:
            rows.insert(0, ("Skinned (the oracle's start; context)", data["skinned"]["summary"]))
        n = len(data["instances"])
        if oracle:
            rows.append((f"Oracle from the skinned start ({oracle['converged']}/{n} converged)", oracle))
        if data.get("oracle_refined"):
            refined = data["oracle_refined"]["summary"]
            rows.append((f"Oracle refining PhysDrape (T=15) ({refined['converged']}/{n} converged)", refined))
            reference = data["reference"]["summary"]
            rows.append((f"Reference (lower E_total per instance; {reference['from_refinement']}/{n} from the "
                         "refinement)", reference))
        out += _table(rows, timing=timing, oracle=has_oracle)
        sources = {d["source"] for d in results["ablation_definitions"].values()}
        if sources == {"switched"}:
            how = "switched at inference on the full model, not retrained"
        elif sources == {"retrained"}:
            how = "separately trained checkpoints, one per variant"
        else:
            how = "mixed: rows marked (switched) are switched at inference on the full model, not retrained"
        out += ["", f"## Table 2 — module ablation ({how})", ""]
        rows = []
        for k, d in results["ablation_definitions"].items():
            mark = " (switched)" if d["source"] == "switched" and sources != {"switched"} else ""
            steps = f", T = {d['steps']}" if d["steps"] else ""
            rows.append((f"{d['label']}{mark}{steps}", data["rows"][f"ablation:{k}"]["summary"]))
        out += _table(rows, timing=timing, oracle=has_oracle)
    out += ["", "## Context: published numbers (not comparable)", "",
            f"Table 1 of the paper — {PUBLISHED_NOTE}:", ""] + _published(PUBLISHED_MAIN)
    out += ["", f"Table 2 of the paper — {PUBLISHED_NOTE}:", ""] + _published(PUBLISHED_ABLATION)
    if results.get("notes"):
        out += ["", "Notes:"] + [f"- {n}" for n in results["notes"]]
    return "\n".join(out) + "\n"


def _atomic_write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _finite_or_none(value):
    """The results with NaN/inf floats as null (strict JSON)."""
    if isinstance(value, dict):
        return {k: _finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_none(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_results(results: dict, out_dir: str | os.PathLike, *, stem: str = "eval") -> tuple[Path, Path]:
    """Write `<stem>.json` (every number) and `<stem>.md` (the tables) atomically into out_dir."""
    out_dir = Path(out_dir)
    json_path, md_path = out_dir / f"{stem}.json", out_dir / f"{stem}.md"
    _atomic_write(json_path, json.dumps(_finite_or_none(results), indent=1, allow_nan=False) + "\n")
    _atomic_write(md_path, render_markdown(results))
    return json_path, md_path
