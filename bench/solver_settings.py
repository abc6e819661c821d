"""The two-level solver's settings side by side: E_total over the teacher drapes and wall time, at T steps.

Run: .venv/bin/python bench/solver_settings.py --checkpoint src/physdrape/assets/models/cpu_default \
    [--config configs/global/full_energy.yaml] [--setting NAME=KEY:VALUE,...] [--steps 1 2 3 4 6 15] \
    [--out results/solver_settings]

On the held-out validation set of CONFIG's data section (`physdrape.train.validation`: garments
and bodies never trained on, each with its teacher drape, the two-level solver run 100 steps from
the same X_init with `physdrape.train.instances.TEACHER_SETTINGS`), every setting drapes every
instance at every T twice: the solver alone from X_init (Δx = 0, f̂ = 0, then the handler;
`PhysDrape.physics_only`) and the checkpoint's full model (GNN → solver → handler). A setting
overrides fields of the checkpoint's `ModelConfig` (default settings: ``checkpoint``, its own
config; ``no_refactor_warmup``: the coarse space factored with the body planes only, not at each
of the first steps; ``refactor_every_step``: the coarse space factored at every step). Per setting, row and T: the mean E_total over the set divided by the teacher
drapes' mean, E_strain likewise, and the median over instances of one drape's wall time (one
torch thread; X_init is not included, it is the same for every row). Settings run interleaved
instance by instance, so a change in the machine's load hits all of them alike. Writes <out>.md
and <out>.json with the command, the commit and the load average.
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import sys
import time
from dataclasses import fields

import torch
from held_out import energies, full_model, validation_batches
from report import source_lines, write_report

from physdrape.model import ModelConfig
from physdrape.provenance import provenance

DEFAULT_SETTINGS = ("checkpoint=", "no_refactor_warmup=refactor_first:0", "refactor_every_step=refactor_every:1")


def parse_setting(text: str) -> tuple[str, dict]:
    """NAME=KEY:VALUE,... → (NAME, {KEY: VALUE}) with VALUE typed as the ModelConfig field."""
    name, sep, body = text.partition("=")
    if not sep or not name:
        raise SystemExit(f"--setting {text!r}: give NAME=KEY:VALUE,... (empty after '=' for the checkpoint's own)")
    types = {f.name: type(getattr(ModelConfig(), f.name)) for f in fields(ModelConfig)}
    out = {}
    for item in filter(None, body.split(",")):
        key, sep, value = item.partition(":")
        if not sep or key not in types:
            raise SystemExit(f"--setting {text!r}: {item!r} is not KEY:VALUE with KEY a ModelConfig field")
        try:
            if types[key] is bool:
                if value.lower() not in ("true", "false"):
                    raise ValueError("give true or false")
                out[key] = value.lower() == "true"
            elif types[key] is type(None):  # an optional field that defaults to None: null, or a number
                out[key] = None if value.lower() == "null" else (int(value) if value.lstrip("-").isdigit()
                                                                 else float(value))
            else:
                out[key] = types[key](value)
        except ValueError as exc:
            raise SystemExit(f"--setting {text!r}: {value!r} is not a valid {key} ({exc})") from None
    return name, out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--config", default="configs/global/full_energy.yaml",
                        help="run config whose data section names the validation set")
    parser.add_argument("--setting", action="append", metavar="NAME=KEY:VALUE,...",
                        help=f"repeatable (default: {' '.join(DEFAULT_SETTINGS)})")
    parser.add_argument("--steps", type=int, nargs="+", default=[1, 2, 3, 4, 6, 15])
    parser.add_argument("--out", default="results/solver_settings")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings = dict(parse_setting(s) for s in (args.setting or DEFAULT_SETTINGS))
    batches = validation_batches(args.config)
    models = {name: full_model(args.checkpoint, **override) for name, override in settings.items()}
    yardstick = full_model(args.checkpoint)  # every energy with the checkpoint's own contact term
    sums = {(n, row, t): [0.0, 0.0, []] for n in models for row in ("solver", "model") for t in args.steps}
    teacher_total = teacher_strain = 0.0
    with torch.no_grad():
        for batch in batches:
            drape = batch.drape
            total, strain = energies(batch.teacher, drape, yardstick)
            teacher_total, teacher_strain = teacher_total + total, teacher_strain + strain
            for t in args.steps:
                for name, model in models.items():
                    for row, run in (("solver", model.physics_only), ("model", model)):
                        run(drape, steps=t)  # warm-up: caches of the topology
                        start = time.perf_counter()
                        x = run(drape, steps=t).x
                        wall = time.perf_counter() - start
                        total, strain = energies(x, drape, yardstick)
                        cell = sums[(name, row, t)]
                        cell[0] += total
                        cell[1] += strain
                        cell[2].append(wall)
    load = os.getloadavg()
    result = [{"setting": n, "override": settings[n], "row": row, "steps": t, "energy_ratio": e / teacher_total,
               "strain_ratio": s / teacher_strain, "wall_ms_median": 1e3 * statistics.median(w)}
              for (n, row, t), (e, s, w) in sums.items()]
    command = shlex.join(["python", "bench/solver_settings.py", *sys.argv[1:]])
    info = provenance()
    lines = ["# The two-level solver's settings side by side", "", *source_lines(command, info),
             f"Load average at the end: {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; torch threads 1; "
             f"{len(batches)} validation instances of `{args.config}`; checkpoint `{args.checkpoint}`.", "",
             "Settings (fields of the checkpoint's ModelConfig overridden): " + "; ".join(
                 f"**{n}**: {o or 'none'}" for n, o in settings.items()), "",
             "E/teacher: mean E_total over the set / the teacher drapes' mean; E_strain likewise; wall: median "
             "over instances of one drape's time, X_init excluded. solver: Δx = 0, f̂ = 0 (then the handler); "
             "model: GNN → solver → handler.", "",
             "| setting | row | T | E/teacher | E_strain/teacher | wall [ms] |", "|---|---|---:|---:|---:|---:|"]
    for r in sorted(result, key=lambda r: (r["row"], r["steps"], r["setting"])):
        lines.append(f"| {r['setting']} | {r['row']} | {r['steps']} | {r['energy_ratio']:.3f} | "
                     f"{r['strain_ratio']:.3f} | {r['wall_ms_median']:.0f} |")
    write_report(args.out, lines, {"command": command, "provenance": info, "load_average": load,
                                   "config": args.config, "checkpoint": args.checkpoint, "rows": result})


if __name__ == "__main__":
    main()
