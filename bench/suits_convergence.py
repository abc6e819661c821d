"""How far the solver's steps take the MakeHuman suits: E_total against T, piece crossings, and
where the oracle's polish moves the pieces.

Run: .venv/bin/python bench/suits_convergence.py [--makehuman ../shared/data/makehuman_cc0]
     [--eval results/eval.json] [--checkpoint src/physdrape/assets/models/cpu_default]
     [--steps 3 15 30 60] [--no-polish] [--out results/suits_convergence]

The suits are the instances of `physdrape eval --makehuman` (the same layout, bodies and wear),
and their reference energies those of the evaluation record `--eval` (per instance the lowest
E_total among its oracle runs that converged, `physdrape.eval.summary.reference`).
Per suit: GNN only (X_init + Δx: no solver, no handler), and per T the model (GNN → solver →
handler) and the solver alone (Δx = 0, f̂ = 0, then the handler), each drape's share of X_init's
excess energy over the reference that it leaves (1 at X_init, 0 at the reference; a suit's E_total
itself can be near 0 or negative, its gravity term being measured from the evaluation's datum), the
set's E_total over the reference as `results/eval.md` gives it (the mean over the suits over the
references' mean), and each drape's piece crossings (intersecting face pairs whose faces belong to
different pieces: the solver's layer pairs are the template's, so a piece that slides far over
another could pass through it unseen by its energy). With the polish (the default), the oracle is
run again from the model's T = 15 drape with the evaluation's settings, as the evaluation's
refinement is: its E_total, its crossings, and per piece the mean vertical move [mm] from the
T = 15 drape to it, which says what the steps leave unsettled. One torch thread. Writes <out>.md and
<out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import glob
import os
import sys
import time

import numpy as np
import torch
from eval_record import suit_instances
from report import page_head, write_report

from physdrape.api.specs import garment_template
from physdrape.checkpoint import load_model
from physdrape.eval import evaluate as ev
from physdrape.garments.pieces import garment_parts
from physdrape.geometry.intersections import piece_crossings
from physdrape.model import Variant
from physdrape.physics.forces import energy_terms


def crossings(x: torch.Tensor, faces: np.ndarray, piece: np.ndarray) -> int:
    return piece_crossings(x.detach().double().cpu().numpy(), faces, piece)


def measure(x: torch.Tensor, batch, contact: ev.Contact, reference: float, faces: np.ndarray,
            piece: np.ndarray) -> dict:
    terms = {name: float(value.sum()) for name, value in energy_terms(x, batch.cloth).items()}
    total = float(ev.total_energy(x, batch, contact)[0])
    return {"energy_total": total, "excess_J": total - reference,
            "strain": terms["strain"], "gravity": terms["gravity"], "layer": terms.get("layer"),
            "crossings": crossings(x, faces, piece)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--makehuman", default="../shared/data/makehuman_cc0")
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--steps", type=int, nargs="+", default=[3, 15, 30, 60])
    parser.add_argument("--no-polish", action="store_true", help="skip the oracle run from the T = 15 drape")
    parser.add_argument("--out", default="results/suits_convergence")
    args = parser.parse_args()
    torch.set_num_threads(1)
    instances, references, record, config = suit_instances(args.eval, args.makehuman)
    model, _ = load_model(args.checkpoint, variant=Variant.FULL)
    gnn_only, _ = load_model(args.checkpoint, variant=Variant.GNN_ONLY)
    contact = ev.Contact.of(model)
    rows = []
    for inst, ref in zip(instances, references):
        batch, _, _ = inst.batch()
        template = garment_template(glob.glob(os.path.join(args.makehuman, inst.garment, "*.mhclo"))[0])
        faces = np.asarray(template.faces, np.int64)
        piece = garment_parts(template.verts, faces).piece
        row = {"garment": inst.garment, "verts": inst.num_verts, "pieces": np.bincount(piece).tolist(),
               "reference": ref["energy_total"], "reference_source": ref["source"], "steps": {},
               "x_init": measure(batch.x_init, batch, contact, ref["energy_total"], faces, piece)}

        def gap(cell: dict, row=row) -> dict:
            return {**cell, "gap_left": cell["excess_J"] / row["x_init"]["excess_J"]}

        with torch.no_grad():
            row["gnn_only"] = gap(measure(ev.run_model(gnn_only, batch, steps=None)[0], batch, contact,
                                          ref["energy_total"], faces, piece))
            for steps in args.steps:
                cell = {}
                for name, network in (("model", True), ("solver", False)):
                    x, wall = ev.run_model(model, batch, steps=steps, network=network)
                    cell[name] = {**gap(measure(x, batch, contact, ref["energy_total"], faces, piece)),
                                  "wall_s": wall}
                    if network and steps == 15:
                        x15 = x
                row["steps"][str(steps)] = cell
        if not args.no_polish:
            x15 = x15 if 15 in args.steps else ev.run_model(model, batch, steps=15)[0]
            start = time.perf_counter()
            result = ev.run_oracle(batch, config, contact, x15)
            polished = result.x.to(x15.dtype)
            move = 1e3 * (polished - x15)[:, 1].double()
            counts = np.bincount(piece)
            row["polish"] = {**gap(measure(polished, batch, contact, ref["energy_total"], faces, piece)),
                             "reason": result.reason, "iterations": len(result.history) - 1,
                             "wall_s": time.perf_counter() - start,
                             "piece_mean_dy_mm": [float(move[torch.from_numpy(piece == p)].mean())
                                                  for p in range(len(counts))],
                             "x15_crossings": crossings(x15, faces, piece)}
        rows.append(row)
        print(f"[suits] {inst.garment}: " + ", ".join(
            f"T={t} {c['model']['gap_left']:.3f}" for t, c in row["steps"].items()), file=sys.stderr, flush=True)
    command, prov, head = page_head("The MakeHuman suits: E_total against solver steps, piece crossings, what the "
                                    "polish moves")
    load = os.getloadavg()
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; references from `{args.eval}` (its commit "
             f"{record['versions']['git_commit'][:7]}); one torch thread; load average at the end "
             f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             "Gap left: the drape's E_total − reference over X_init's (1 at X_init, 0 at the reference); in "
             "brackets its piece crossings (intersecting face pairs of different pieces). GNN only: X_init + Δx; "
             "model: GNN → solver T → "
             "handler; solver: Δx = 0, f̂ = 0, then the handler. The last row: the set's mean E_total over the "
             "references' mean, as `results/eval.md` gives it.", "",
             "| suit | verts (pieces) | reference [J] (from) | X_init crossings | GNN only | " + " | ".join(
                 f"T = {t}: model | solver" for t in args.steps) + " |",
             "|---|---|---|---|---|" + "---|---|" * len(args.steps)]
    for row in rows:
        cells = []
        for t in args.steps:
            c = row["steps"][str(t)]
            cells += [f"{c[name]['gap_left']:.3f} ({c[name]['crossings']})" for name in ("model", "solver")]
        lines.append(f"| {row['garment']} | {row['verts']} ({'+'.join(map(str, row['pieces']))}) | "
                     f"{row['reference']:.4f} ({row['reference_source']}) | {row['x_init']['crossings']} | "
                     f"{row['gnn_only']['gap_left']:.3f} ({row['gnn_only']['crossings']}) | "
                     + " | ".join(cells) + " |")
    mean_ref = float(np.mean([row["reference"] for row in rows]))
    means = [f"{np.mean([row['steps'][str(t)][name]['energy_total'] for row in rows]) / mean_ref:.3f}"
             for t in args.steps for name in ("model", "solver")]
    gnn_mean = np.mean([row["gnn_only"]["energy_total"] for row in rows]) / mean_ref
    lines.append(f"| all: mean E_total / mean reference | | | | {gnn_mean:.3f} | " + " | ".join(means) + " |")
    lines.append("")
    lines.append("Excess over the reference [J] (E_total − reference; X_init's in the first column):")
    lines.append("")
    lines.append("| suit | X_init | GNN only | " + " | ".join(f"T = {t}: model | solver" for t in args.steps) + " |")
    lines.append("|---|---|---|" + "---|---|" * len(args.steps))
    for row in rows:
        cells = [f"{row['steps'][str(t)][name]['excess_J']:+.4f}" for t in args.steps for name in ("model", "solver")]
        lines.append(f"| {row['garment']} | {row['x_init']['excess_J']:+.4f} | {row['gnn_only']['excess_J']:+.4f} | "
                     + " | ".join(cells) + " |")
    if not args.no_polish:
        lines += ["", "The oracle from the model's T = 15 drape (the evaluation's settings): its end, its gap left "
                  "(below 0 where it ends lower than the evaluation's reference), the piece crossings of the "
                  "T = 15 drape and of the polished one, the excess of the T = 15 drape's strain and gravity terms "
                  "over the polished one's, and per piece (in the order of the sizes above) the mean vertical move "
                  "from the T = 15 drape to the polished one:", "",
                  "| suit | end (iterations, wall [s]) | polished: gap left | crossings T = 15 → polished | "
                  "strain excess [J] | gravity excess [J] | mean vertical move per piece [mm] |",
                  "|---|---|---|---|---|---|---|"]
        for row in rows:
            p, m15 = row["polish"], row["steps"].get("15", {}).get("model")
            strain = f"{m15['strain'] - p['strain']:+.4f}" if m15 else "–"
            gravity = f"{m15['gravity'] - p['gravity']:+.4f}" if m15 else "–"
            lines.append(f"| {row['garment']} | {p['reason']} ({p['iterations']}, {p['wall_s']:.0f}) | "
                         f"{p['gap_left']:+.3f} | {p['x15_crossings']} → {p['crossings']} | {strain} | {gravity} | "
                         + ", ".join(f"{v:+.1f}" for v in p["piece_mean_dy_mm"]) + " |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "eval": args.eval,
                                   "checkpoint": args.checkpoint, "steps": args.steps, "load_average": list(load),
                                   "suits": rows})


if __name__ == "__main__":
    main()
