"""The evaluation protocol (paper Tables 1–2, DESIGN.md Sec. 4–5): model rows vs. the physics oracle.

Instances (`physdrape.eval.instances`): instance i drapes test garment i mod G in pose i div G,
on a posed Anny body drawn from its own seed (evaluation seed, set, garment, pose), default
material; by default every test garment of the split once (`EvalConfig.poses_per_garment` times),
and `EvalConfig.instances` = N takes the first N of that one list, so an instance is the same
whatever N. Every instance is draped alone (batch of one), so wall times are per garment.
Optionally the CC0 MakeHuman garments are evaluated the same way, as a second set.

Rows of Table 1, all from ONE checkpoint (the variant is an inference-time switch of the model):

- ``gnn_only``: X = X_init + Δx (variant GNN_ONLY: no solver, no handler; a multi-piece garment's
  outer vertices that Δx drove into the piece under them pushed back out, part of the network's move);
- ``post_col``: GNN → stretching solver (T = eval_steps) → collision handler with δ = 1 applied
  as post-processing (variant POST_COL; the paper's Post-Col is a model *trained* without the
  handler — here it is the full model's weights with the learned δ replaced by 1);
- ``physdrape_t3`` / ``physdrape_t15``: the full model (GNN → solver T → handler, learned δ);
- ``physics_only_t3`` / ``physics_only``: the same solver (T = 3 / 15) and handler with the network
  left out (Δx = 0, f̂ = 0): what the network adds is the difference to ``physdrape_t3`` /
  ``physdrape_t15`` (the report's "What the network adds" table);
- ``oracle``: `physdrape.physics.relax` from the skinned start (penalty contact, default tol 1e-2, a
  wall-time budget per instance); its row reports whether it converged. It does not involve the
  model, so its results are cached per instance (`physdrape.eval.reference_cache`) and reused by
  the evaluation of any checkpoint on the same instances and settings;
- ``oracle_refined``: the same `relax` started from the PhysDrape (T=15) drape (the refinement mode
  users call to polish a drape); its wall time includes the model's;
- ``oracle_settled``: the same `relax` started from the model's drape at T =
  `EvalConfig.oracle_settle_steps` (60), a drape settled further along the slow modes (a long
  sleeve sliding down the arm); its wall time includes the model's;
- ``reference``: per instance the lowest-E_total of the oracle results that converged (none: of
  all): the best equilibrium found from any start. The oracle is a local minimiser, and it stops in the equilibrium its
  start leads to: from the skinned start it can settle in a higher-energy equilibrium than the
  one near the model's drape, and from the T = 15 drape in a higher one than from a drape settled
  further; the reference is what every ratio is measured against (without the other starts: the
  oracle).

Table 2 (module ablation: GNN / +solver / +collision / full): from separately trained checkpoints
when given, otherwise the same switches of the main checkpoint (labelled as such).

Metrics per row and instance: `physdrape.physics.metrics.drape_metrics` (E_strain, E_bend, B2G %,
close %, residual force) plus the total static energy the oracle minimises (strain + bend +
gravity + contact penalty) and the wall time; for a garment of several pieces, also the drape's
piece crossings (summed over the instances in the tables). Energies are also
given as the ratio of the row's mean to the reference's mean over the same instances, over all
instances and per garment category (the category a split garment's name carries,
`physdrape.eval.summary.by_category`).
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import asdict, dataclass
from typing import NamedTuple

import torch

from physdrape.checkpoint import load_model
from physdrape.eval import summary as agg
from physdrape.eval.config import EvalConfig, reference_cache_dir
from physdrape.eval.instances import (
    Instance,
    InstanceInput,
    makehuman_instances,
    split_instances,
)
from physdrape.eval.reference_cache import ReferenceCache, reference_key
from physdrape.eval.report import PUBLISHED_ABLATION, PUBLISHED_MAIN, PUBLISHED_NOTE
from physdrape.geometry.intersections import piece_crossings
from physdrape.geometry.topology import connected_components
from physdrape.model import DrapeInput, PhysDrape, Variant
from physdrape.physics import energy
from physdrape.physics.metrics import drape_metrics
from physdrape.physics.oracle import relax, silenced
from physdrape.provenance import provenance

__all__ = [
    "ABLATION_ROWS",
    "MAIN_ROWS",
    "EvalConfig",
    "InstanceInput",
    "RowSpec",
    "evaluate",
]


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
    RowSpec("gnn_only", "GNN only", Variant.GNN_ONLY, None,
            "X_init + Δx of the GNN (no solver, no handler; a multi-piece garment's outer vertices that Δx drove into "
            "the piece under them pushed back out, as every row's network move)"),
    RowSpec("post_col", "Post-Col", Variant.POST_COL, None,
            "GNN → solver (T = eval_steps) → handler with δ = 1 as post-processing (full model's weights, learned δ replaced by 1)"),
    RowSpec("physdrape_t3", "PhysDrape (T=3)", Variant.FULL, 3, "GNN → solver T = 3 → handler (learned δ)"),
    RowSpec("physdrape_t15", "PhysDrape (T=15)", Variant.FULL, 15, "GNN → solver T = 15 → handler (learned δ)"),
    RowSpec("physics_only_t3", "No network (T=3; context)", Variant.FULL, 3,
            "X_init → solver T = 3 with Δx = 0, f̂ = 0 → handler: the PhysDrape (T=3) row without its network",
            network=False),
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



def _test_instances(config: EvalConfig, body) -> list[Instance]:
    """The test set's instances (`physdrape.eval.instances.split_instances`); bench/ times the
    protocol's instances through it."""
    return split_instances(config, body)


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
    """The drape's metrics and E_total; for a garment of several pieces, also its piece crossings
    (`geometry.intersections.piece_crossings`: the layer order's pairs hold each vertex on its side,
    and do not see a piece that is already through another)."""
    m = drape_metrics(x, batch.garments, batch.bodies, batch.body_index, cloth=batch.cloth)
    out = {name: values[0] for name, values in m.as_dict().items()}
    out["energy_total"] = float(total_energy(x, batch, contact)[0])
    faces = batch.garments.faces.cpu().numpy()
    piece = connected_components(x.shape[0], faces)
    if piece.max(initial=0) > 0:
        out["piece_crossings"] = piece_crossings(x.detach().double().cpu().numpy(), faces, piece)
    return out


@torch.no_grad()
def total_energy(x: torch.Tensor, batch: DrapeInput, contact: Contact) -> torch.Tensor:
    """`physics.energy.total_energy` of one evaluation batch [J] (G,): what the oracle minimises
    (penalty contact at vertices and face centroids; the batch's materials)."""
    return energy.total_energy(x, batch.cloth, batch.bodies, batch.body_index, contact_stiffness=contact.stiffness,
                               margin=contact.margin)


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


def oracle_settings(config: EvalConfig, contact: Contact) -> dict:
    """The settings `run_oracle` runs with, as recorded in the reference cache's keys."""
    return {"contact": "penalty", "tol": config.oracle_tol, "max_iters": config.oracle_max_iters,
            "time_budget_s": config.oracle_budget_s, "contact_stiffness": contact.stiffness,
            "margin": contact.margin, "dtype": config.dtype}


def _oracle_fields(result) -> dict:
    """What an oracle record holds beyond the metrics of its drape (the reference cache keeps these)."""
    terms = {name: float(value.sum()) for name, value in result.energy_terms.items()}
    return {"wall_s": float(result.wall_time), "converged": bool(result.converged), "reason": result.reason,
            "oracle_residual": float(result.residual.max()), "iterations": len(result.history) - 1,
            "oracle_energy_total": terms["total"], "oracle_energy_terms": terms,
            "history": [{"iteration": h.iteration, "energy": h.energy, "residual": h.residual, "wall": h.wall}
                        for h in result.history]}


def _oracle_record(result, batch: DrapeInput, contact: Contact) -> dict:
    return {**_metrics(result.x.to(batch.x_init.dtype), batch, contact), **_oracle_fields(result)}


def _oracle_from(batch: DrapeInput, start: torch.Tensor, drape_wall_s: float, config: EvalConfig,
                 contact: Contact) -> dict:
    """The record of the oracle from one of the model's drapes: its wall time includes the drape's
    (`drape_wall_s`, the kinematic init and the model), the oracle's own is `oracle_wall_s`."""
    rec = _oracle_record(run_oracle(batch, config, contact, start), batch, contact)
    rec["oracle_wall_s"] = rec["wall_s"]
    rec["wall_s"] += drape_wall_s
    return rec


def skinned_oracle(batch: DrapeInput, start: torch.Tensor | None, config: EvalConfig, contact: Contact,
                   cache: ReferenceCache | None) -> dict:
    """The record of the oracle from `start` (None: X_init), from `cache` when it holds this
    instance under these settings (``cached`` says which), else run and added to it."""
    start = batch.x_init if start is None else start
    key = reference_key(batch, start, oracle_settings(config, contact)) if cache is not None else None
    hit = cache.load(key, start.shape[0]) if cache is not None else None
    if hit is not None:
        x, fields = hit
    else:
        result = run_oracle(batch, config, contact, start)
        x, fields = result.x, _oracle_fields(result)
        if cache is not None:
            cache.store(key, x, fields)
    return {**_metrics(x.to(batch.x_init.dtype), batch, contact), **fields, "cached": hit is not None}


# ------------------------------------------------------------------------------------------
# One instance set
# ------------------------------------------------------------------------------------------


#: The model row the oracle refines (EvalConfig.oracle_refine).
REFINED_ROW = "physdrape_t15"

def _evaluate_set(instances: list[Instance], models: dict, rows: dict, config: EvalConfig, contact: Contact,
                  log, cache: ReferenceCache | None = None) -> dict:
    """Per-instance records and summaries of every row (and the oracle) on one instance set, over
    all its instances and per garment category; `cache`: the oracle results from the skinned start."""
    per_row: dict[str, list[dict]] = {key: [] for key in rows}
    oracle: list[dict] = []
    refined: list[dict] = []
    settled: list[dict] = []
    start: list[dict] = []
    plain: list[dict] = []
    refine = config.oracle and config.oracle_refine and REFINED_ROW in rows
    settle = config.oracle and config.oracle_settle_steps > 0 and REFINED_ROW in rows
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
        line = (f"[eval] {inst.set_name} {inst.index + 1}/{len(instances)} {inst.garment} pose {inst.pose_index} "
                f"({inst.num_verts} verts)")
        if config.oracle:
            oracle.append(skinned_oracle(batch, skinned, config, contact, cache))
            line += (f": oracle {oracle[-1]['reason']} in {oracle[-1]['wall_s']:.1f} s"
                     + (" (cached)" if oracle[-1]["cached"] else ""))
        if refine:
            refined.append(_oracle_from(batch, to_refine, per_row[REFINED_ROW][-1]["wall_s"], config, contact))
            line += f"; refined {refined[-1]['reason']} in {refined[-1]['oracle_wall_s']:.1f} s"
        if settle:
            x, wall = run_model(models[rows[REFINED_ROW][0]], batch, steps=config.oracle_settle_steps)
            settled.append(_oracle_from(batch, x, init_s + wall, config, contact))
            line += (f"; from T = {config.oracle_settle_steps} {settled[-1]['reason']} in "
                     f"{settled[-1]['oracle_wall_s']:.1f} s")
        del batch
        log(f"{line}; peak memory {_peak_rss_gib():.1f} GiB")
    reference = agg.reference(oracle, refined, settled) if oracle else []
    ref_summary = agg.oracle_summary(reference) if reference else None
    if ref_summary is not None:
        ref_summary["from_refinement"] = sum(r["source"] == "oracle_refined" for r in reference)
        ref_summary["from_settled"] = sum(r["source"] == "oracle_settled" for r in reference)

    def block(records: list[dict], summarize=agg.summary) -> dict:
        return {"summary": agg.with_ratios(summarize(records), ref_summary), "per_instance": records}

    result = {
        "instances": [inst.describe() for inst in instances],
        "rows": {key: block(recs) for key, recs in per_row.items()},
        "oracle": block(oracle, agg.oracle_summary) if oracle else None,
        "oracle_refined": block(refined, agg.oracle_summary) if refined else None,
        "oracle_settled": block(settled, agg.oracle_summary) if settled else None,
        "reference": ({"summary": agg.with_ratios(dict(ref_summary), ref_summary),
                       "per_instance": [{k: v for k, v in r.items() if k != "history"} for r in reference]}
                      if reference else None),
        "x_init": block(start),
    }
    if plain:
        result["skinned"] = block(plain)
    context = {"x_init": start, **({"skinned": plain} if plain else {})}
    extra = {name: recs for name, recs in (("oracle", oracle), ("oracle_refined", refined),
                                           ("oracle_settled", settled), ("reference", reference)) if recs}
    every_row = {**context, **per_row, **extra}
    result["categories"] = agg.by_category([inst.category for inst in instances], every_row, reference or None)
    result["poses"] = agg.by_pose([inst.pose_index for inst in instances], every_row, reference or None)
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
    cache_dir = reference_cache_dir(config) if config.oracle else None
    cache = ReferenceCache(cache_dir) if cache_dir is not None else None
    garments = len({inst.garment_index for inst in instances})
    log(f"[eval] test set: {len(instances)} instances ({garments} test garments, up to "
        f"{max(inst.pose_index for inst in instances) + 1} pose(s) each, body seed {config.seed})"
        + (f"; oracle results from the skinned start cached in {cache_dir}" if cache is not None else ""))
    rows = {**main_rows, **abl_rows}
    sets = {"test": _evaluate_set(instances, models, rows, config, contact, log, cache)}
    notes = []
    if config.makehuman_dir:
        try:
            mh, notes = makehuman_instances(config, body)
        except Exception as exc:
            mh, notes = [], [f"MakeHuman set skipped ({type(exc).__name__}: {exc})"]
        for note in notes:
            log(f"[eval] {note}")
        if mh:
            log(f"[eval] makehuman set: {len(mh)} instances")
            sets["makehuman"] = _evaluate_set(mh, models, rows, config, contact, log, cache)
    if cache is not None:
        log(f"[eval] reference cache {cache_dir}: {cache.hits} oracle result(s) reused, {cache.misses} computed")

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
                              + ("; the same from the PhysDrape (T=15) drape (refined)" if config.oracle_refine else "")
                              + (f"; the same from the model's drape at T = {config.oracle_settle_steps} (settled)"
                                 if config.oracle_settle_steps else "")
                              + ("; the reference is per instance the lowest-E_total of these that converged"
                                 if config.oracle_refine or config.oracle_settle_steps else ""))
                             if config.oracle else None,
        "published": {"note": PUBLISHED_NOTE, "table1": PUBLISHED_MAIN, "table2": PUBLISHED_ABLATION},
        "reference_cache": ({"dir": str(cache_dir), "hits": cache.hits, "misses": cache.misses}
                            if cache is not None else None),
        "sets": sets,
        "notes": notes,
        "total_wall_s": time.perf_counter() - t_start,
    }


