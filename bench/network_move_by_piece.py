"""How much of the settling move the network makes, per garment piece: the MakeHuman suits' upper
and lower pieces beside test-split tops.

Run: .venv/bin/python bench/network_move_by_piece.py [--checkpoint src/physdrape/assets/models/cpu_default]
     [--makehuman ../shared/data/makehuman_cc0] [--eval results/eval.json] [--tops 10]
     [--settled-steps 60] [--out results/network_move_by_piece]

Per piece of each suit (`physdrape eval --makehuman`'s instances, layout, bodies and wear) and per
test-split top (every third of the first 3 × `--tops` test instances): the mean distance of its
vertices from X_init to the model's drape at T = `--settled-steps` (the settled drape, within a
fraction of a per cent of the evaluation's reference energy), the mean distance left from the
network's drape X_init + Δx (GNN only) to it, their ratio (1: the network moved nothing toward
the settled drape; 0: it reached it), the mean vertical move needed and made [mm], and the mean
vertical component of the coarse part of the solver's first step at X_init, which the network reads
among its inputs (`ModelConfig.step_inputs`). One torch thread. Writes <out>.md and <out>.json
with the command and the commit.
"""

from __future__ import annotations

import argparse
import glob
import os

import numpy as np
import torch
from eval_record import suit_instances, test_instances
from report import page_head, write_report

from physdrape.api.specs import garment_template
from physdrape.checkpoint import load_model
from physdrape.eval import evaluate as ev
from physdrape.garments.pieces import garment_parts
from physdrape.model import Variant


def piece_rows(name: str, batch, piece: np.ndarray, model, gnn_only, settled_steps: int) -> list[dict]:
    """One row per piece: the distances and vertical moves [mm] described in the module docstring."""
    with torch.no_grad():
        x_gnn = ev.run_model(gnn_only, batch, steps=None)[0].double()
        settled = ev.run_model(model, batch, steps=settled_steps)[0].double()
        inputs = gnn_only.node_inputs(batch).double()
    x_init = batch.x_init.double()
    # the step parts are the inputs' last six columns (block-Jacobi move, coarse move) unless a
    # Newton move follows them
    readable = gnn_only.config.step_inputs and not gnn_only.config.step_newton_iterations
    coarse_dy = inputs[:, -2] if readable else None
    rows = []
    for p in range(int(piece.max()) + 1):
        mask = torch.from_numpy(piece == p)
        needed = (settled - x_init)[mask]
        left = (settled - x_gnn)[mask]
        rows.append({
            "garment": name, "piece": p, "verts": int(mask.sum()),
            "height_m": float(settled[mask, 1].mean()),
            "needed_mm": 1e3 * float(needed.norm(dim=1).mean()),
            "left_mm": 1e3 * float(left.norm(dim=1).mean()),
            "needed_dy_mm": 1e3 * float(needed[:, 1].mean()),
            "made_dy_mm": 1e3 * float((x_gnn - x_init)[mask, 1].mean()),
            "coarse_step_dy_mm": None if coarse_dy is None else 1e3 * float(coarse_dy[mask].mean()),
        })
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--makehuman", default="../shared/data/makehuman_cc0")
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record whose instances to draw")
    parser.add_argument("--tops", type=int, default=10, help="test-split tops (every third test instance)")
    parser.add_argument("--settled-steps", type=int, default=60)
    parser.add_argument("--out", default="results/network_move_by_piece")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model, _ = load_model(args.checkpoint, variant=Variant.FULL)
    gnn_only, _ = load_model(args.checkpoint, variant=Variant.GNN_ONLY)
    rows = []
    suits, _, _, _ = suit_instances(args.eval, args.makehuman)
    for inst in suits:
        batch, _, _ = inst.batch()
        template = garment_template(glob.glob(os.path.join(args.makehuman, inst.garment, "*.mhclo"))[0])
        parts = garment_parts(template.verts, np.asarray(template.faces, np.int64))
        for row in piece_rows(inst.garment, batch, parts.piece, model, gnn_only, args.settled_steps):
            row["set"] = "suit"
            row["role"] = "lower" if parts.lower is not None and row["piece"] == parts.lower else "upper"
            rows.append(row)
    tops, _, _ = test_instances(args.eval, 3 * args.tops)
    for inst in tops[::3]:
        batch = inst.batch()[0]
        for row in piece_rows(inst.garment, batch, np.zeros(len(batch.x_init), np.int64), model, gnn_only,
                              args.settled_steps):
            rows.append({**row, "set": "test top", "role": "top"})
    command, prov, head = page_head("How much of the settling move the network makes, per garment piece")
    load = os.getloadavg()

    def fmt(value):
        return "–" if value is None else f"{value:+.1f}"

    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; settled drape: the model at T = {args.settled_steps}; instances of "
             f"`{args.eval}`; one torch thread; load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.",
             "",
             "Per piece: mean distance [mm] from X_init to the settled drape (needed) and from the network's drape "
             "(GNN only) to it (left), left / needed (1: the network moved nothing toward it), the mean vertical move "
             "needed and made by the network [mm], and the mean vertical part of the coarse move of the solver's "
             "first step at X_init, among the network's inputs [mm].", "",
             "| set | garment | piece (role) | verts | height [m] | needed [mm] | left [mm] | left / needed | "
             "dy needed [mm] | dy made [mm] | coarse step dy [mm] |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['set']} | {r['garment']} | {r['piece']} ({r['role']}) | {r['verts']} | "
                     f"{r['height_m']:.2f} | {r['needed_mm']:.1f} | {r['left_mm']:.1f} | "
                     f"{r['left_mm'] / r['needed_mm']:.2f} | {fmt(r['needed_dy_mm'])} | {fmt(r['made_dy_mm'])} | "
                     f"{fmt(r['coarse_step_dy_mm'])} |")
    lines += ["", "Mean of left / needed by role (pieces weighted alike):", "", "| role | pieces | left / needed |",
              "|---|---:|---:|"]
    summary = {}
    for role in ("upper", "lower", "top"):
        ratios = [r["left_mm"] / r["needed_mm"] for r in rows if r["role"] == role]
        if ratios:
            summary[role] = float(np.mean(ratios))
            lines.append(f"| {role} | {len(ratios)} | {summary[role]:.2f} |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "checkpoint": args.checkpoint,
                                   "settled_steps": args.settled_steps, "load_average": list(load),
                                   "summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
