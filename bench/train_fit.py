"""How a checkpoint drapes the instances it was trained on against the held-out ones: the share of
X_init's excess energy over the teacher drapes that it removes on each.

Run: .venv/bin/python bench/train_fit.py --checkpoint src/physdrape/assets/models/cpu_default \
    [--config configs/global/gnn_step_inputs.yaml] [--train-samples 32] [--steps 3 15] [--out results/training_fit]

The training instances are drawn as a training step draws them (`DrapeSource.make_batch`, seeds
0, 125, 250, ... so repeats are possible), from CONFIG's instance cache; the held-out ones are its
validation set (garments and bodies never trained on). Per set and row: the set's mean E_total
over the teacher drapes' mean, and the share of X_init's excess over the teachers that the row
removes (1 − (E − teacher) / (E_X_init − teacher), over the set's sums). A share higher on the
training instances than on the held-out ones says the network fits the instances it has seen
better than it generalises (whether more instances then help is for a run to say:
`docs/training/README.md`, "More instances"). Rows: X_init, GNN only (X_init + Δx) and the full
model at each T (GNN → solver → handler). One torch thread.
Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import os

import torch
from held_out import energies, full_model
from report import page_head, write_report

from physdrape.config_io import load_config
from physdrape.train.data import DrapeSource
from physdrape.train.trainer import TrainConfig


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--config", default="configs/global/gnn_step_inputs.yaml",
                        help="the run config whose instance cache the checkpoint was trained on")
    parser.add_argument("--train-samples", type=int, default=32)
    parser.add_argument("--steps", type=int, nargs="+", default=[3, 15])
    parser.add_argument("--out", default="results/training_fit")
    args = parser.parse_args()
    torch.set_num_threads(1)
    train_config = load_config(TrainConfig, args.config)
    source = DrapeSource(train_config.data, model=train_config.model)
    if source.cache is None:
        raise SystemExit(f"{args.config}: its data section has no instance cache")
    model = full_model(args.checkpoint)
    sets = {"training": [source.make_batch([125 * k]) for k in range(args.train_samples)],
            "held-out": source.validation()}
    sums: dict[str, dict[str, float]] = {}
    with torch.no_grad():
        for name, batches in sets.items():
            cell = sums.setdefault(name, {})
            for batch in batches:
                drapes = {"teacher": batch.teacher.to(batch.drape.x_init.dtype), "X_init": batch.drape.x_init}
                for steps in args.steps:
                    out = model(batch.drape, steps=steps)
                    drapes["GNN only"] = out.x_gnn
                    drapes[f"T = {steps}"] = out.x
                for row, x in drapes.items():
                    cell[row] = cell.get(row, 0.0) + energies(x, batch.drape, model)[0]
    rows = []
    for name, cell in sums.items():
        excess = cell["X_init"] - cell["teacher"]
        for row, total in cell.items():
            if row != "teacher":
                rows.append({"set": name, "row": row, "energy_ratio": total / cell["teacher"],
                             "removed": 1.0 - (total - cell["teacher"]) / excess})
    command, prov, head = page_head("The checkpoint on its training instances and on held-out ones")
    load = os.getloadavg()
    names = list(dict.fromkeys(r["row"] for r in rows))
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`, instance cache of `{args.config}`: {args.train_samples} training "
             f"draws (seeds 0, 125, ...), {len(sets['held-out'])} held-out instances; one torch thread; load "
             f"average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             "E / teacher: the set's mean E_total over its teacher drapes' mean; in brackets the share of X_init's "
             "excess over the teachers that the row removes.", "",
             "| set | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for name in sets:
        by = {r["row"]: r for r in rows if r["set"] == name}
        lines.append(f"| {name} | " + " | ".join(
            f"{by[n]['energy_ratio']:.4f} ({100 * by[n]['removed']:.0f} %)" for n in names) + " |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "load_average": load,
                                   "checkpoint": args.checkpoint, "config": args.config, "rows": rows})


if __name__ == "__main__":
    main()
