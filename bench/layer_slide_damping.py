"""What the layer pairs' tangential preconditioner share β costs and buys on the MakeHuman suits.

Run: .venv/bin/python bench/layer_slide_damping.py [--part solver|inputs|reach] [--betas 0.1 0.03 0.01 0]
     [--steps 3 15 60] [--makehuman ../shared/data/makehuman_cc0] [--eval results/eval.json]
     [--checkpoint src/physdrape/assets/models/cpu_default] [--out results/layer_slide_damping]

A layer pair's block in the solver's preconditioner is k (n nᵀ + β (I − n nᵀ)) with β =
`physics.forces.LAYER_SLIDE_DAMPING`: the energy resists only the outer piece's approach along n,
and β slows the pieces' relative sliding, which the pairs (found on the template) describe only
while it is small. `--part solver` sets the solver's β (`physics.forces.LAYER_SLIDE_DAMPING`),
`--part inputs` the β of the first step that the network reads among its inputs
(`physdrape.model.physdrape.INPUT_LAYER_SLIDE`), each on its module for the run; `--part reach`
sets instead how far beyond its gap [m] a layer pair's block still acts in the solver's steps
(`physics.forces.LAYER_LINK_REACH`; `--betas` then lists reaches, a large one keeps every pair's
block). Per value: the suits
(`physdrape eval --makehuman`'s instances and wear) at GNN only and the model at each T, the set's
mean E_total over the references' mean of the evaluation record `--eval` (as `results/eval.md`
gives it) and the piece crossings summed over the suits (face pairs of different pieces that
intersect: a piece through another, which the energy of the template's pairs no longer sees). One
torch thread. Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import glob
import os

import numpy as np
import torch
from eval_record import suit_instances
from report import page_head, write_report

import physdrape.model.physdrape as physdrape_model
import physdrape.physics.forces as forces
from physdrape.api.specs import garment_template
from physdrape.checkpoint import load_model
from physdrape.eval import evaluate as ev
from physdrape.garments.pieces import garment_parts
from physdrape.geometry.intersections import piece_crossings
from physdrape.model import Variant


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=["solver", "inputs", "reach"], default="solver",
                        help="whose β to set: the solver's preconditioner, or that of the step the network reads; "
                             "reach: the solver's layer-link reach instead of a β")
    parser.add_argument("--betas", type=float, nargs="+", default=[0.1, 0.03, 0.01, 0.0],
                        help="the values of β (with --part reach: of the reach [m])")
    parser.add_argument("--steps", type=int, nargs="+", default=[3, 15, 60])
    parser.add_argument("--makehuman", default="../shared/data/makehuman_cc0")
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--out", default="results/layer_slide_damping")
    args = parser.parse_args()
    torch.set_num_threads(1)
    instances, references, _, _ = suit_instances(args.eval, args.makehuman)
    model, _ = load_model(args.checkpoint, variant=Variant.FULL)
    gnn_only, _ = load_model(args.checkpoint, variant=Variant.GNN_ONLY)
    contact = ev.Contact.of(model)
    batches, meshes = [], []
    for inst in instances:
        batches.append(inst.batch()[0])
        template = garment_template(glob.glob(os.path.join(args.makehuman, inst.garment, "*.mhclo"))[0])
        faces = np.asarray(template.faces, np.int64)
        meshes.append((faces, garment_parts(template.verts, faces).piece))
    reference = float(np.mean([r["energy_total"] for r in references]))
    module, attribute = {"solver": (forces, "LAYER_SLIDE_DAMPING"), "inputs": (physdrape_model, "INPUT_LAYER_SLIDE"),
                         "reach": (forces, "LAYER_LINK_REACH")}[args.part]
    symbol = "reach [m]" if args.part == "reach" else "β"
    shipped_beta = getattr(module, attribute)
    rows = []
    columns = [("gnn_only", None)] + [(f"t{t}", t) for t in args.steps]
    try:
        for beta in args.betas:
            setattr(module, attribute, beta)
            row = {"beta": beta, "energy_ratio": {}, "crossings": {}, "per_suit": []}
            energies = {name: [] for name, _ in columns}
            crossings = {name: 0 for name, _ in columns}
            with torch.no_grad():
                for batch, mesh in zip(batches, meshes):
                    for name, steps in columns:
                        x = ev.run_model(gnn_only if steps is None else model, batch, steps=steps)[0]
                        energies[name].append(float(ev.total_energy(x, batch, contact)[0]))
                        crossings[name] += piece_crossings(x.detach().double().cpu().numpy(), *mesh)
            row["energy_ratio"] = {name: float(np.mean(values)) / reference for name, values in energies.items()}
            row["crossings"] = crossings
            row["energy_total"] = energies
            rows.append(row)
            print(f"[beta {beta}] " + ", ".join(f"{n} {row['energy_ratio'][n]:.4f} ({crossings[n]})"
                                                for n, _ in columns), flush=True)
    finally:
        setattr(module, attribute, shipped_beta)
    title = {"solver": "The layer pairs' tangential share in the solver's preconditioner",
             "inputs": "The layer pairs' tangential share in the step the network reads",
             "reach": "How far beyond its gap a layer pair's preconditioner block acts"}[args.part]
    command, prov, head = page_head(f"{title}, on the MakeHuman suits")
    load = os.getloadavg()
    names = ["GNN only"] + [f"T = {t}" for t in args.steps]
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; {len(instances)} suits of `{args.eval}` with its references; "
             f"{symbol} set: `{module.__name__}.{attribute}` (shipped {shipped_beta}); one torch thread; load "
             f"average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             f"Per {symbol}: the set's mean E_total over the references' mean, and in brackets the piece crossings "
             "summed over the suits (intersecting face pairs of different pieces).", "",
             f"| {symbol} | " + " | ".join(names) + " |", "|---:|" + "---:|" * len(names)]
    for row in rows:
        cells = [f"{row['energy_ratio'][n]:.4f} ({row['crossings'][n]})" for n, _ in columns]
        lines.append(f"| {row['beta']:g} | " + " | ".join(cells) + " |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "checkpoint": args.checkpoint,
                                   "eval": args.eval, "part": args.part, "shipped_beta": shipped_beta,
                                   "steps": args.steps,
                                   "load_average": list(load), "suits": [inst.garment for inst in instances],
                                   "rows": rows})


if __name__ == "__main__":
    main()
