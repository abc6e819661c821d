"""Where the model's drapes lie above the converged reference on the test split: per energy term,
the collision handler's share, and how the excess shrinks with the solver's steps.

Run: .venv/bin/python bench/excess_breakdown.py [--eval results/eval.json]
     [--checkpoint src/physdrape/assets/models/cpu_default] [--steps 3 15 30 60] [--instances N]
     [--out results/excess_breakdown]

The instances are the evaluation's test instances (`physdrape.eval.instances.split_instances`,
the first `--instances`, default all of the record's), their references those of the evaluation
record `--eval` (per instance the lowest E_total among its oracle runs that converged,
`physdrape.eval.summary.reference`). Per T, the model (GNN → solver T → handler) and the
same weights without the handler (`Variant.GNN_SOLVER`: the solver's drape before the handler
pushes the vertices within the margin ε out to δ ε): the set's mean E_total over the references'
mean, as `results/eval.md` gives it, and the excess over the reference split into the energy
terms (strain, bending, gravity with the contact penalty), each as a share of the references'
mean. The handler's share is the part of the model's excess that the handler adds: the contact
penalty lets a garment rest a fraction of a millimetre inside the margin where the body holds it
up, the handler lifts it out (DESIGN.md: the handler's margin is the penalty's ε), which costs
strain and gravity energy that the reference, an equilibrium of the penalty, does not pay. The
handler's vertex push is split by where the vertices were: the drape without the handler with
only its vertices inside the body, then only those in the margin, pushed out to ε. One
torch thread. Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np
import torch
from eval_record import test_instances
from report import page_head, write_report

from physdrape.checkpoint import load_model
from physdrape.eval import evaluate as ev
from physdrape.model import Variant
from physdrape.physics.forces import energy_terms

#: The model's variants measured: with the collision handler (the drape) and without it.
VARIANTS = {"model": Variant.FULL, "no handler": Variant.GNN_SOLVER}
#: The drape without the handler, its vertices inside the body (d < 0) or in the margin (0 ≤ d < ε)
#: alone moved out to ε along the body normal: the handler's vertex push (Eq. 11, δ = 1) split by
#: where the vertices were.
LIFTS = ("lift inside", "lift margin")


def measure(x: torch.Tensor, batch, contact: ev.Contact) -> dict:
    """E_total [J] of a drape and its strain, bending and gravity-with-contact parts."""
    terms = {name: float(value.sum()) for name, value in energy_terms(x, batch.cloth).items()}
    total = float(ev.total_energy(x, batch, contact)[0])
    metrics = ev._metrics(x, batch, contact)
    return {"energy_total": total, "strain": terms["strain"], "bend": terms["bend"],
            "gravity_contact": total - terms["strain"] - terms["bend"], "b2g_percent": metrics["b2g_percent"]}


def lifts(x: torch.Tensor, batch, contact: ev.Contact) -> dict:
    """`measure` of x with the vertices inside the body, then those in the margin, pushed out to
    ε along the normal (each alone), and how many vertices each moved."""
    query = batch.bodies.query(x, body_index=batch.body_index)
    d, normal = query.signed_distance.to(x.dtype), query.normal.to(x.dtype)
    push = (contact.margin - d).clamp_min(0.0)[:, None] * normal
    inside = d < 0
    cells = {}
    for name, chosen in zip(LIFTS, (inside, ~inside & (d < contact.margin))):
        cells[name] = {**measure(x + push * chosen[:, None], batch, contact), "vertices": int(chosen.sum())}
    return cells


def reference_terms(ref: dict) -> dict:
    """The same parts of a reference record of the evaluation."""
    return {"energy_total": ref["energy_total"], "strain": ref["strain"], "bend": ref["bend"],
            "gravity_contact": ref["energy_total"] - ref["strain"] - ref["bend"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--steps", type=int, nargs="+", default=[3, 15, 30, 60])
    parser.add_argument("--instances", type=int, default=None, help="the first N test instances (default: all)")
    parser.add_argument("--out", default="results/excess_breakdown")
    args = parser.parse_args()
    torch.set_num_threads(1)
    instances, references, record = test_instances(args.eval, args.instances)
    models = {name: load_model(args.checkpoint, variant=variant)[0] for name, variant in VARIANTS.items()}
    contact = ev.Contact.of(models["model"])
    rows = []
    for inst, ref in zip(instances, references):
        batch = inst.batch().drape
        row = {"garment": inst.garment, "category": inst.category, "reference": reference_terms(ref), "steps": {}}
        with torch.no_grad():
            for steps in args.steps:
                cell = {}
                for name, model in models.items():
                    x = ev.run_model(model, batch, steps=steps)[0]
                    cell[name] = measure(x, batch, contact)
                    if name == "no handler":
                        cell.update(lifts(x, batch, contact))
                row["steps"][str(steps)] = cell
        rows.append(row)
        print(f"[excess] {inst.garment}: " + ", ".join(
            f"T={t} {c['model']['energy_total'] / row['reference']['energy_total']:.4f}"
            for t, c in row["steps"].items()), file=sys.stderr, flush=True)

    def mean(values) -> float:
        return float(np.mean(list(values)))

    ref_mean = mean(row["reference"]["energy_total"] for row in rows)
    parts = ("strain", "bend", "gravity_contact")
    summary = {}
    for t in args.steps:
        cell = {}
        for name in (*VARIANTS, *LIFTS):
            drapes = [row["steps"][str(t)][name] for row in rows]
            cell[name] = {"ratio": mean(d["energy_total"] for d in drapes) / ref_mean,
                          "b2g_percent": mean(d["b2g_percent"] for d in drapes),
                          **{f"{part}_excess": mean(d[part] - row["reference"][part] for d, row in zip(drapes, rows))
                             / ref_mean for part in parts}}
        for name in LIFTS:
            cell[name]["vertices"] = mean(row["steps"][str(t)][name]["vertices"] for row in rows)
        excess = cell["model"]["ratio"] - 1.0
        cell["handler_share"] = (cell["model"]["ratio"] - cell["no handler"]["ratio"]) / excess if excess else None
        summary[str(t)] = cell
    command, prov, head = page_head("The test split's excess over the converged reference: per term, the handler's "
                                    "share, against T")
    load = os.getloadavg()
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; {len(rows)} test instances and their references from `{args.eval}` "
             f"(its commit {record['versions']['git_commit'][:7]}); one torch thread; load average at the end "
             f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             "E / ref: the set's mean E_total over the references' mean (as `results/eval.md`). model: GNN → "
             "solver T → handler; no handler: the same drape before the handler. Excess per term: the mean of "
             "(term − the reference's term) over the references' mean E_total, in percent; the three add up to "
             "(E / ref − 1). Handler's share: the part of the model's excess that the handler adds.", "",
             "| T | model E / ref | no handler E / ref | handler's share | strain excess [%] | bending excess [%] "
             "| gravity + contact excess [%] | no handler: strain / bending / gravity + contact [%] "
             "| B2G [%] model / no handler |",
             "|---:|---:|---:|---:|---:|---:|---:|---|---|"]
    for t in args.steps:
        c = summary[str(t)]
        m, n = c["model"], c["no handler"]
        share = "–" if c["handler_share"] is None else f"{100 * c['handler_share']:.0f} %"
        lines.append(f"| {t} | {m['ratio']:.4f} | {n['ratio']:.4f} | {share} | {100 * m['strain_excess']:+.2f} | "
                     f"{100 * m['bend_excess']:+.2f} | {100 * m['gravity_contact_excess']:+.2f} | "
                     f"{100 * n['strain_excess']:+.2f} / {100 * n['bend_excess']:+.2f} / "
                     f"{100 * n['gravity_contact_excess']:+.2f} | {m['b2g_percent']:.2f} / {n['b2g_percent']:.2f} |")
    lines += ["", "What the handler's push costs, by where the vertices were: the drape without the handler, its "
              "vertices inside the body (d < 0) or those in the margin (0 ≤ d < ε) alone pushed out to ε along the "
              "body normal (Eq. 11 with δ = 1, without the handler's passes over face centroids, overlapping body "
              "parts and layers), E / ref and the mean number of vertices moved per drape:", "",
              "| T | no handler | inside pushed out | vertices inside | margin pushed out | vertices in the margin "
              "| model |",
              "|---:|---:|---:|---:|---:|---:|---:|"]
    for t in args.steps:
        c = summary[str(t)]
        inside, margin = c["lift inside"], c["lift margin"]
        lines.append(f"| {t} | {c['no handler']['ratio']:.4f} | {inside['ratio']:.4f} | {inside['vertices']:.1f} | "
                     f"{margin['ratio']:.4f} | {margin['vertices']:.0f} | {c['model']['ratio']:.4f} |")
    lines += ["", "Per instance, the model's E_total over its reference, and in brackets the instance's share of the "
              "set's excess at that T (its E_total − reference over the sum of those over the instances: the set's "
              "E / ref weighs each instance by its reference energy):", "",
              "| instance | category | reference [J] | " + " | ".join(f"T = {t}" for t in args.steps)
              + " | no handler, T = " + str(args.steps[-1]) + " |",
              "|---|---|---:|" + "---:|" * (len(args.steps) + 1)]
    excess = {t: sum(row["steps"][str(t)]["model"]["energy_total"] - row["reference"]["energy_total"] for row in rows)
              for t in args.steps}
    for row in rows:
        ref = row["reference"]["energy_total"]
        cells = [f"{row['steps'][str(t)]['model']['energy_total'] / ref:.4f} "
                 f"({100 * (row['steps'][str(t)]['model']['energy_total'] - ref) / excess[t]:.0f} %)"
                 for t in args.steps]
        last = row["steps"][str(args.steps[-1])]["no handler"]["energy_total"] / ref
        lines.append(f"| {row['garment']} | {row['category']} | {ref:.4f} | " + " | ".join(cells) + f" | {last:.4f} |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "eval": args.eval,
                                   "checkpoint": args.checkpoint, "steps": args.steps, "load_average": list(load),
                                   "summary": summary, "instances": rows})


if __name__ == "__main__":
    main()
