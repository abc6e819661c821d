"""How far the solver should start along the network's move: the model with its solver starting
from X_init + g Δx, on the held-out validation set (where g is chosen) and on the test split.

Run: .venv/bin/python bench/move_gain.py [--gains 1 1.15 1.3 1.45 1.6 2] [--eval results/eval.json]
     [--checkpoint src/physdrape/assets/models/cpu_default] [--config configs/global/gnn_energy.yaml]
     [--out results/move_gain]

`ModelConfig.eval_move_gain` g extrapolates the network's move before the solver (GNN only stays
X_init + Δx). Held-out: the validation instances of the run config `--config` (`physdrape.train.
validation`: E_total over the teacher drapes', the two-level solver run to near convergence from
the same X_init). Test split: the evaluation's test instances and references of the record
`--eval` (E_total over the reference, as `results/eval.md`). T = 3 and 15, one torch thread.
Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import torch
from eval_record import test_instances
from report import page_head, write_report

from physdrape.checkpoint import load_model
from physdrape.config_io import load_config
from physdrape.eval import evaluate as ev
from physdrape.model import Variant
from physdrape.train.data import DrapeSource
from physdrape.train.trainer import TrainConfig
from physdrape.train.validation import Validator


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gains", type=float, nargs="+", default=[1.0, 1.15, 1.3, 1.45, 1.6, 2.0])
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--config", default="configs/global/gnn_energy.yaml",
                        help="the run config whose data section names the validation set")
    parser.add_argument("--out", default="results/move_gain")
    args = parser.parse_args()
    if any(not g > 0 for g in args.gains):
        raise SystemExit("--gains takes numbers > 0")
    torch.set_num_threads(1)
    model, _ = load_model(args.checkpoint, variant=Variant.FULL)
    train_config = load_config(TrainConfig, args.config)
    validator = Validator(DrapeSource(train_config.data, model=train_config.model).validation())
    instances, references, record = test_instances(args.eval)
    contact = ev.Contact.of(model)
    batches = [inst.batch().drape for inst in instances]
    ref_sum = sum(r["energy_total"] for r in references)
    rows = []
    for gain in args.gains:
        model.config = replace(model.config, eval_move_gain=gain)
        held = validator(model)
        test = {}
        with torch.no_grad():
            for steps in (3, 15):
                total = sum(float(ev.total_energy(model(batch, steps=steps).x, batch, contact)[0])
                            for batch in batches)
                test[str(steps)] = total / ref_sum
        rows.append({"gain": gain, "held_out": {t: held[f"t{t}/energy_ratio"] for t in ("3", "15")}, "test": test})
        print(f"[move_gain] g = {gain}: held-out T=3 {held['t3/energy_ratio']:.4f} "
              f"T=15 {held['t15/energy_ratio']:.4f}; test T=3 {test['3']:.4f} T=15 {test['15']:.4f}", flush=True)
    command, prov, head = page_head("The solver's start along the network's move: X_init + g Δx")
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; held-out: the {len(validator.batches)} validation instances of "
             f"`{args.config}` (E_total over the teacher drapes'); test: the {len(batches)} test instances and "
             f"references of `{args.eval}` (its commit {record['versions']['git_commit'][:7]}; E_total over the "
             "reference); one torch thread. GNN only (X_init + Δx) does not depend on g.", "",
             "| g | held-out T = 3 | held-out T = 15 | test T = 3 | test T = 15 |", "|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['gain']:g} | {r['held_out']['3']:.4f} | {r['held_out']['15']:.4f} | {r['test']['3']:.4f} | "
                     f"{r['test']['15']:.4f} |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "checkpoint": args.checkpoint,
                                   "config": args.config, "eval": args.eval, "rows": rows})


if __name__ == "__main__":
    main()
