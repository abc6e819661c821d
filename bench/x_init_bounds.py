"""X_init's compression bound side by side: the held-out set draped from X_init made with each
lower bound of its strain limiter.

Run: .venv/bin/python bench/x_init_bounds.py --checkpoint src/physdrape/assets/models/cpu_default \
    [--config configs/global/gnn_step_inputs.yaml] [--min-stretch none 0.85 0.9 0.95] [--steps 3 15] \
    [--out results/x_init_bounds]

On the held-out validation set of CONFIG's data section (garments and bodies never trained on,
each with its teacher drape from the instance cache), every instance's X_init is made again by
the pipeline with the skinning transfer's `min_stretch` set to each value (`none`: compressed
edges left as skinned; the other limits as the transfer's), and draped from there by the
checkpoint: X_init itself, GNN only (X_init + Δx, no solver, no handler), the full model (GNN →
solver → handler) and the solver alone (Δx = 0, f̂ = 0, then the handler) at each T. Per value
and row: the mean E_total over the set divided by the teacher drapes' mean (the same teachers
for every value), E_strain likewise. One torch thread. Writes <out>.md and <out>.json with the
command, the commit and the load average.
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys

import torch
from held_out import energies, full_model
from report import source_lines, write_report

from physdrape.config_io import load_config
from physdrape.physics import Material
from physdrape.pipeline import DrapePipeline, Job
from physdrape.provenance import provenance
from physdrape.train.data import DrapeSource
from physdrape.train.trainer import TrainConfig


def parse_bound(text: str) -> float | None:
    return None if text.lower() == "none" else float(text)


def remade_batches(source: DrapeSource, min_stretch: float | None) -> list:
    """The validation instances' drape inputs with X_init made afresh under `min_stretch`."""
    pipeline = DrapePipeline(source.body, dtype=source.dtype, x_init_limits={"min_stretch": min_stretch})
    instances = source.cache.part("val")[:source.config.validation_count]
    return [pipeline.build([Job(source.templates[inst.garment], 0, Material(**inst.material))],
                           source.validation_pool.state(inst.body)) for inst in instances]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--config", default="configs/global/gnn_step_inputs.yaml",
                        help="run config whose data section names the validation set")
    parser.add_argument("--min-stretch", nargs="+", default=["none", "0.85", "0.9", "0.95"])
    parser.add_argument("--steps", type=int, nargs="+", default=[3, 15])
    parser.add_argument("--out", default="results/x_init_bounds")
    args = parser.parse_args()
    torch.set_num_threads(1)
    train_config = load_config(TrainConfig, args.config)
    source = DrapeSource(train_config.data, model=train_config.model)
    if source.cache is None:
        raise SystemExit(f"{args.config}: its data section has no instance cache, so no validation set")
    count = len(source.cache.part("val")[:source.config.validation_count])
    teachers = [source.cache.tensors("val", i)[1] for i in range(count)]
    model = full_model(args.checkpoint)
    rows = []
    for text in args.min_stretch:
        bound = parse_bound(text)
        sums: dict[str, list[float]] = {}
        teacher_total = teacher_strain = 0.0
        with torch.no_grad():
            for drape, teacher in zip(remade_batches(source, bound), teachers):
                total, strain = energies(teacher.to(drape.x_init.dtype), drape, model)
                teacher_total, teacher_strain = teacher_total + total, teacher_strain + strain
                drapes = {"X_init": drape.x_init}
                for t in args.steps:
                    out = model(drape, steps=t)
                    drapes["GNN only"] = out.x_gnn  # X_init + Δx, whatever T
                    drapes[f"model T = {t}"] = out.x
                    drapes[f"solver T = {t}"] = model.physics_only(drape, steps=t).x
                for name, x in drapes.items():
                    total, strain = energies(x, drape, model)
                    cell = sums.setdefault(name, [0.0, 0.0])
                    cell[0], cell[1] = cell[0] + total, cell[1] + strain
        for name, (total, strain) in sums.items():
            rows.append({"min_stretch": bound, "row": name, "energy_ratio": total / teacher_total,
                         "strain_ratio": strain / teacher_strain})
        print(f"[x_init_bounds] min_stretch {text}: " + ", ".join(
            f"{r['row']} {r['energy_ratio']:.3f}" for r in rows if r["min_stretch"] == bound), file=sys.stderr,
            flush=True)
    load = os.getloadavg()
    command = shlex.join(["python", "bench/x_init_bounds.py", *sys.argv[1:]])
    info = provenance()
    names = list(dict.fromkeys(r["row"] for r in rows))
    lines = ["# X_init's compression bound side by side", "", *source_lines(command, info),
             f"Load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; torch threads 1; "
             f"{len(teachers)} validation instances of `{args.config}`; checkpoint `{args.checkpoint}`.", "",
             "E/teacher: mean E_total over the set / the teacher drapes' mean (E_strain likewise in brackets), "
             "X_init made by the pipeline with the strain limiter's lower bound min_stretch on edge length / rest "
             "length (none: compressed edges left as skinned). GNN only: X_init + Δx; model: GNN → solver → "
             "handler; solver: Δx = 0, f̂ = 0, then the handler.", "",
             "| min_stretch | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for text in args.min_stretch:
        bound = parse_bound(text)
        cells = {r["row"]: r for r in rows if r["min_stretch"] == bound}
        lines.append(f"| {text} | " + " | ".join(
            f"{cells[n]['energy_ratio']:.3f} ({cells[n]['strain_ratio']:.2f})" for n in names) + " |")
    write_report(args.out, lines, {"command": command, "provenance": info, "load_average": load,
                                   "config": args.config, "checkpoint": args.checkpoint, "rows": rows})


if __name__ == "__main__":
    main()
