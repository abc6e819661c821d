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

import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from functools import partial
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from physdrape.body.skinning_transfer import LOCAL_STRETCH_BOUND
from physdrape.checkpoint import load_model
from physdrape.eval.report import PUBLISHED_ABLATION, PUBLISHED_MAIN, PUBLISHED_NOTE, provenance
from physdrape.physics.metrics import drape_metrics
from physdrape.model import DrapeInput, PhysDrape, Variant
from physdrape.physics import Material
from physdrape.physics.contact import penalty_contact_energy
from physdrape.physics.forces import energy_terms
from physdrape.physics.oracle import relax, silenced
from physdrape.pipeline import DEFAULT_DTYPE, POSE_DTYPE, DrapePipeline, Job, Template
from physdrape.body.pool import BodyPool
from physdrape.train.data import DataConfig, load_templates

__all__ = [
    "ABLATION_ROWS",
    "MAIN_ROWS",
    "EvalConfig",
    "InstanceInput",
    "RowSpec",
    "evaluate",
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
    garments with more vertices (0 = no cap); dtype: of the garments, bodies and physics handed
    to the model ("float32"/"float64"; default: the API's, so the evaluation measures what
    `Draper` runs; the network keeps its own); threads: torch threads (0: torch's default)."""

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
    dtype: str = str(DEFAULT_DTYPE).removeprefix("torch.")
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


def _instance_batch(pipeline: DrapePipeline, pool, template: Template, body: int) -> InstanceInput:
    """`template` on pool body `body`, default material, built by the drape pipeline exactly as
    `Draper.drape` builds it (see `InstanceInput`)."""
    state = pool.state(body)
    t0 = time.perf_counter()
    x_init = pipeline.x_init(template, state)
    init_s = time.perf_counter() - t0
    with torch.no_grad():
        skinned = replace(pipeline.transfer(template), max_stretch=LOCAL_STRETCH_BOUND).apply(state)[0]
    drape = pipeline.build([Job(template, 0, Material(), x_init)], state)
    return InstanceInput(drape, init_s, skinned.to(pipeline.dtype))


def _instances(set_name: str, templates: list[Template], pool, config: EvalConfig, body) -> list[_Instance]:
    """Instance i of a set: garment `garment_of(i)` on pool body i (the pool's seed fixes the bodies)."""
    pipeline = DrapePipeline(body, dtype=getattr(torch, config.dtype))
    out = []
    for i in range(len(pool)):
        g = garment_of(i, len(pool), len(templates))
        out.append(_Instance(set_name, i, templates[g].name, g, i, templates[g].num_verts,
                             partial(_instance_batch, pipeline, pool, templates[g], i)))
    return out


def _test_instances(config: EvalConfig, body) -> list[_Instance]:
    data = DataConfig(split_dir=config.split_dir, split_seed=0, subset="test", max_garments=config.max_garments)
    templates = load_templates(data)
    if not templates:
        raise ValueError(f"no test garments in the split ({config.split_dir or 'the default cache'})")
    pool = BodyPool(body, config.instances, seed=config.seed, dtype=POSE_DTYPE)
    return _instances("test", templates, pool, config, body)


def _makehuman_instances(config: EvalConfig, body) -> tuple[list[_Instance], list[str]]:
    """Instances of the CC0 MakeHuman garments (skipped with a note if anything is missing)."""
    from physdrape.garments.mhclo import load_mhclo

    notes = []
    root = Path(config.makehuman_dir).expanduser()
    files = sorted(root.glob("*/*.mhclo")) + sorted(root.glob("*.mhclo"))
    if not files:
        return [], [f"MakeHuman: no .mhclo under {root}; skipped"]
    templates = []
    for path in files:
        try:
            g = load_mhclo(path)
            if config.makehuman_max_verts and len(g.verts) > config.makehuman_max_verts:
                notes.append(f"MakeHuman: {path.name} skipped ({len(g.verts)} vertices > makehuman_max_verts "
                             f"{config.makehuman_max_verts})")
                continue
            templates.append(Template.from_mesh(g.verts, g.faces, name=path.stem))
        except Exception as exc:  # noqa: BLE001 (an optional set: report and go on)
            notes.append(f"MakeHuman: {path.name} skipped ({type(exc).__name__}: {exc})")
    if not templates:
        return [], notes
    pool = BodyPool(body, len(templates) * config.makehuman_instances, seed=config.seed + 1, dtype=POSE_DTYPE)
    return _instances("makehuman", templates, pool, config, body), notes


# ------------------------------------------------------------------------------------------
# Running rows
# ------------------------------------------------------------------------------------------


class Contact(NamedTuple):
    """The body contact of the problem every row is measured on: the model's penalty stiffness
    k_c [J/m³] and margin ε [m] (`ModelConfig.contact_stiffness`, `ModelConfig.margin`)."""

    stiffness: float
    margin: float

    @staticmethod
    def of(model: PhysDrape) -> Contact:
        return Contact(model.config.contact_stiffness, model.config.margin)


def _metrics(x: torch.Tensor, batch: DrapeInput, contact: Contact) -> dict[str, float]:
    m = drape_metrics(x, batch.garments, batch.bodies, batch.body_index, cloth=batch.cloth)
    out = {name: float(getattr(m, name)[0]) for name in m.__dataclass_fields__}
    out["energy_total"] = float(total_energy(x, batch, contact)[0])
    return out


@torch.no_grad()
def total_energy(x: torch.Tensor, batch: DrapeInput, contact: Contact) -> torch.Tensor:
    """E_strain + E_bend + E_grav + E_contact per garment [J] (G,): what the oracle minimises
    (penalty contact at vertices and face centroids; the batch's materials)."""
    terms = energy_terms(x, batch.cloth)
    e_contact = penalty_contact_energy(x, batch.cloth, batch.bodies, batch.body_index, stiffness=contact.stiffness,
                                       margin=contact.margin)
    return terms["strain"] + terms["bend"] + terms["gravity"] + e_contact


@torch.no_grad()
def run_model(model: PhysDrape, batch: DrapeInput, *, steps: int | None, network: bool = True) -> tuple[torch.Tensor, float]:
    """(drape x, wall seconds) of one model call (network=False: `PhysDrape.physics_only`)."""
    t0 = time.perf_counter()
    out = model(batch, steps=steps) if network else model.physics_only(batch, steps=steps)
    return out.x, time.perf_counter() - t0


def run_oracle(batch: DrapeInput, config: EvalConfig, contact: Contact, start: torch.Tensor | None = None):
    """`relax` from `start` (default X_init) on one instance (penalty contact), with the
    configured tol and budget."""
    garment_of_vert = batch.garments.vert_garment
    body_of_garment = torch.zeros(batch.garments.num_garments, dtype=torch.int64).scatter_(0, garment_of_vert, batch.body_index)
    with silenced(1):
        return relax(batch.x_init if start is None else start, batch.cloth, batch.bodies, body_of_garment,
                     contact="penalty", tol=config.oracle_tol, contact_stiffness=contact.stiffness,
                     margin=contact.margin, max_iters=config.oracle_max_iters, time_budget_s=config.oracle_budget_s)


def _oracle_record(result, batch: DrapeInput, contact: Contact) -> dict:
    rec = _metrics(result.x.to(batch.x_init.dtype), batch, contact)
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


def _evaluate_set(instances: list[_Instance], models: dict, rows: dict, config: EvalConfig, contact: Contact,
                  log) -> dict:
    """Per-instance records and summaries of every row (and the oracle) on one instance set."""
    per_row: dict[str, list[dict]] = {key: [] for key in rows}
    oracle: list[dict] = []
    refined: list[dict] = []
    start: list[dict] = []
    plain: list[dict] = []
    refine = config.oracle and config.oracle_refine and REFINED_ROW in rows
    for inst in instances:
        batch, init_s, skinned = inst.batch()
        start.append({**_metrics(batch.x_init, batch, contact), "wall_s": init_s})
        if skinned is not None:
            plain.append({**_metrics(skinned, batch, contact), "wall_s": 0.0})
        to_refine = None
        for key, (model_key, steps, network) in rows.items():
            x, wall = run_model(models[model_key], batch, steps=steps, network=network)
            rec = _metrics(x, batch, contact)
            rec["wall_s"] = init_s + wall  # a drape costs its kinematic init plus the model
            rec["model_wall_s"] = wall
            per_row[key].append(rec)
            if refine and key == REFINED_ROW:
                to_refine = x
        line = f"[eval] {inst.set_name} {inst.index + 1}/{len(instances)} {inst.garment} ({inst.num_verts} verts)"
        if config.oracle:
            oracle.append(_oracle_record(run_oracle(batch, config, contact, skinned), batch, contact))
            line += f": oracle {oracle[-1]['reason']} in {oracle[-1]['wall_s']:.1f} s"
        if refine:
            rec = _oracle_record(run_oracle(batch, config, contact, to_refine), batch, contact)
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
    instances = _test_instances(config, body)
    contact = Contact.of(models["physdrape_t15"])
    sets = {"test": _evaluate_set(instances, models, {**main_rows, **abl_rows}, config, contact, log)}
    notes = []
    if config.makehuman_dir:
        try:
            mh, notes = _makehuman_instances(config, body)
        except Exception as exc:  # noqa: BLE001 (an optional set never sinks the main evaluation)
            mh, notes = [], [f"MakeHuman set skipped ({type(exc).__name__}: {exc})"]
        if mh:
            sets["makehuman"] = _evaluate_set(mh, models, {**main_rows, **abl_rows}, config, contact, log)
        for note in notes:
            log(f"[eval] {note}")

    return {
        "format": "physdrape-eval-1",
        "config": asdict(config),
        "command": command if command is not None else " ".join(sys.argv),
        "versions": provenance(),
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


