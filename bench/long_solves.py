"""Long solves side by side: the solver's step scale decaying at every step (the paper's γ^t)
against decaying over the first `decay_steps` and then holding (`ModelConfig.decay_steps`).

Run: .venv/bin/python bench/long_solves.py [--eval results/eval.json] [--makehuman ../shared/data/makehuman_cc0]
     [--checkpoint src/physdrape/assets/models/cpu_default] [--decay-steps none 15] [--steps 15 30 60 120]
     [--out results/long_solves]

On the evaluation's test instances and (with `--makehuman`) its MakeHuman suits, each with its
converged reference from the evaluation record `--eval`, the model (GNN → solver T → handler) and
the solver alone (Δx = 0, f̂ = 0, then the handler) drape every instance at each T with each
`decay_steps` (`none`: γ^t at every step), the settings taking turns per instance. Per set, row
and T: the set's mean E_total over the references' mean (as `results/eval.md`), the mean B2G %
and the median wall time of one drape. One torch thread. Writes <out>.md and <out>.json with the
command and the commit.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
from dataclasses import replace
from pathlib import Path

import torch
from report import page_head, write_report

from physdrape.body.anny_body import get_anny_body
from physdrape.checkpoint import load_model
from physdrape.eval.config import EvalConfig
from physdrape.eval.evaluate import Contact, run_model, total_energy
from physdrape.eval.instances import makehuman_instances, split_instances
from physdrape.model import PhysDrape, Variant
from physdrape.physics.metrics import b2g_percent


def parse_decay(text: str) -> int | None:
    return None if text.lower() == "none" else int(text)


def with_decay(model: PhysDrape, decay_steps: int | None) -> PhysDrape:
    """The model's weights with the solver's step scale decaying over `decay_steps` steps."""
    other = PhysDrape(replace(model.config, decay_steps=decay_steps)).eval()
    other.load_state_dict(model.state_dict())
    return other


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--makehuman", default="", help="the MakeHuman suits' directory (default: the test set only)")
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--decay-steps", nargs="+", default=["none", "15"])
    parser.add_argument("--steps", type=int, nargs="+", default=[15, 30, 60, 120])
    parser.add_argument("--out", default="results/long_solves")
    args = parser.parse_args()
    torch.set_num_threads(1)
    record = json.loads(Path(args.eval).read_text())
    config = EvalConfig(**{k: v for k, v in record["config"].items() if k in EvalConfig.__dataclass_fields__})
    body = get_anny_body()
    sets = {"test": split_instances(config, body)}
    if args.makehuman:
        sets["suits"] = makehuman_instances(replace(config, makehuman_dir=args.makehuman), body)[0]
    trained, _ = load_model(args.checkpoint, variant=Variant.FULL)
    decays = [parse_decay(text) for text in args.decay_steps]
    models = {decay: with_decay(trained.eval(), decay) for decay in decays}
    contact = Contact.of(trained)
    results = {}
    for name, instances in sets.items():
        key = "test" if name == "test" else "makehuman"
        references = [r["energy_total"] for r in record["sets"][key]["reference"]["per_instance"]]
        if len(references) != len(instances):
            sys.exit(f"{args.eval} has {len(references)} {name} instances, the config gives {len(instances)} here")
        cells: dict = {}
        for instance in instances:
            batch = instance.batch()[0]
            with torch.no_grad():
                for steps in args.steps:
                    for network in (True, False):
                        for decay, model in models.items():
                            x, wall = run_model(model, batch, steps=steps, network=network)
                            cell = cells.setdefault((decay, "model" if network else "solver", steps),
                                                    {"energy": [], "b2g": [], "wall": []})
                            cell["energy"].append(float(total_energy(x, batch, contact)[0]))
                            cell["b2g"].append(float(b2g_percent(x, batch.garments, batch.bodies, batch.body_index)[0]))
                            cell["wall"].append(wall)
        results[name] = [{"decay_steps": decay, "row": row, "steps": steps,
                          "energy_ratio": sum(c["energy"]) / sum(references), "b2g_percent": statistics.mean(c["b2g"]),
                          "wall_median_s": statistics.median(c["wall"]), "energy_total": c["energy"]}
                         for (decay, row, steps), c in cells.items()]
        print(f"[long_solves] {name}: " + ", ".join(
            f"{r['row']} T={r['steps']} decay {r['decay_steps']} {r['energy_ratio']:.4f}" for r in results[name]),
            file=sys.stderr, flush=True)
    command, prov, head = page_head("Long solves: the step scale decaying at every step or over the first steps")
    load = os.getloadavg()
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; references from `{args.eval}` (its commit "
             f"{record['versions']['git_commit'][:7]}); one torch thread; load average at the end "
             f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             "E / ref: the set's mean E_total over the references' mean; B2G [%] the mean; wall: the median of one "
             "drape [s]. decay_steps none: the solver's step t scaled by η γ^t (the paper's schedule); n: by "
             "η γ^min(t, n). model: GNN → solver T → handler; solver: Δx = 0, f̂ = 0, then the handler.", ""]
    for name, rows in results.items():
        lines += [f"## {name} ({len(sets[name])} instances)", "",
                  "| row | T | " + " | ".join(f"decay_steps {text}: E / ref | B2G | wall" for text in args.decay_steps)
                  + " |", "|---|---:|" + "---:|---:|---:|" * len(decays)]
        for row in ("model", "solver"):
            for steps in args.steps:
                by = {r["decay_steps"]: r for r in rows if r["row"] == row and r["steps"] == steps}
                lines.append(f"| {row} | {steps} | " + " | ".join(
                    f"{by[d]['energy_ratio']:.4f} | {by[d]['b2g_percent']:.2f} | {by[d]['wall_median_s']:.2f}"
                    for d in decays) + " |")
        lines.append("")
    write_report(args.out, lines, {"command": command, "provenance": prov, "load_average": load,
                                   "eval_file": args.eval, "checkpoint": args.checkpoint, "results": results})


if __name__ == "__main__":
    main()
