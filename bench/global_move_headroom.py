"""What a global move is worth: the solver's T steps from starts that hold the teacher's move at a given resolution.

Run: .venv/bin/python bench/global_move_headroom.py --checkpoint src/physdrape/assets/models/cpu_default \
    [--config configs/global/full_energy.yaml] [--levels 2 3 4] [--steps 0 3 15] [--out results/global_move_headroom]

On the held-out validation set of CONFIG's data section (`physdrape.train.validation`), each
instance is started from

- ``x_init``: X_init (the solver alone);
- ``gnn``: X_init + Δx of the checkpoint's network (the full model without its f̂);
- ``teacher_translation``: X_init moved as a whole by the teacher's mean move (mass-weighted):
  the part of the global settling that is one translation of the garment;
- ``teacher_on_patches_L``: X_init plus the teacher's move (teacher drape − X_init) fitted, in
  the least-squares sense, on the smooth patches of coarse level L (`CoarseSpace.fit`, the
  two-level solver's coarse space: level 2 has patches of 6–15 vertices, each level up about
  twice as wide): what a network that got the global settling exactly right at that resolution,
  and nothing finer, would hand the solver;
- ``teacher``: the teacher drape itself (the floor: the handler and the solver at the teacher);

and the checkpoint's solver (f̂ = 0) and collision handler run T steps from there (T = 0: the
start as it is, no handler). Per start and T: the mean E_total over the set divided by the teacher
drapes' mean, and E_strain likewise. Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from dataclasses import replace

import torch
from held_out import energies, full_model, validation_batches
from report import source_lines, write_report

from physdrape.physics.coarse_space import CoarseSpace
from physdrape.provenance import provenance


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--config", default="configs/global/full_energy.yaml",
                        help="run config whose data section names the validation set")
    parser.add_argument("--levels", type=int, nargs="+", default=[2, 3, 4])
    parser.add_argument("--steps", type=int, nargs="+", default=[0, 3, 15])
    parser.add_argument("--out", default="results/global_move_headroom")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = full_model(args.checkpoint)
    batches = validation_batches(args.config)
    starts = ["x_init", "gnn", "teacher_translation", *(f"teacher_on_patches_{lv}" for lv in args.levels), "teacher"]
    sums = {(s, t): [0.0, 0.0] for s in starts for t in args.steps}
    teacher_total = teacher_strain = 0.0
    with torch.no_grad():
        for batch in batches:
            drape, teacher = batch.drape, batch.teacher
            total, strain = energies(teacher, drape, model)
            teacher_total, teacher_strain = teacher_total + total, teacher_strain + strain
            move = teacher - drape.x_init
            mass = drape.cloth.mass[:, None]
            begin = {"x_init": drape.x_init, "gnn": model(drape, steps=0).x_gnn, "teacher": teacher,
                     "teacher_translation": drape.x_init + (mass * move).sum(0) / mass.sum()}  # one garment
            for lv in args.levels:
                begin[f"teacher_on_patches_{lv}"] = drape.x_init + CoarseSpace(
                    drape.cloth, levels=lv, smoothing=model.config.coarse_smoothing).fit(move)
            for name, x0 in begin.items():
                for t in args.steps:
                    x = x0 if t == 0 else model.physics_only(replace(drape, x_init=x0), steps=t).x
                    total, strain = energies(x, drape, model)
                    sums[(name, t)][0] += total
                    sums[(name, t)][1] += strain
    rows = [{"start": s, "steps": t, "energy_ratio": e / teacher_total, "strain_ratio": st / teacher_strain}
            for (s, t), (e, st) in sums.items()]
    command = shlex.join(["python", "bench/global_move_headroom.py", *sys.argv[1:]])
    info = provenance()
    lines = ["# What a global move is worth", "", *source_lines(command, info),
             f"{len(batches)} validation instances of `{args.config}`; checkpoint `{args.checkpoint}` (its solver, "
             "f̂ = 0, and its collision handler); torch threads 1.", "",
             "E/teacher: mean E_total over the set / the teacher drapes' mean (E_strain likewise) after T solver steps "
             "and the handler from each start (T = 0: the start itself). teacher_on_patches_L: X_init plus the "
             "teacher's move fitted on the smooth patches of coarse level L.", "",
             "| start | " + " | ".join(f"T={t} E/teacher | T={t} E_strain/teacher" for t in args.steps) + " |",
             "|---|" + "---:|---:|" * len(args.steps)]
    for s in starts:
        cells = [f"{sums[(s, t)][0] / teacher_total:.3f} | {sums[(s, t)][1] / teacher_strain:.3f}" for t in args.steps]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    write_report(args.out, lines, {"command": command, "provenance": info, "config": args.config,
                                   "checkpoint": args.checkpoint, "rows": rows})


if __name__ == "__main__":
    main()
