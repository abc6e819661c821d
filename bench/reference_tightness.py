"""How low the evaluation's references are: the oracle run again from the model's T = 60 drape,
against each test instance's reference, and the set's rows against the lower of the two.

Run: .venv/bin/python bench/reference_tightness.py [--eval results/eval.json]
     [--checkpoint src/physdrape/assets/models/cpu_default] [--steps 60] [--instances N]
     [--out results/reference_tightness]

An evaluation's reference is per instance the lowest E_total of the physics oracle's runs, each
stopped where its residual over the free vertices and its last relative energy change fall under
their tolerances: from the skinned garment and from the model's T = 15 drape, and, since this
bench showed what it adds (`results/reference_tightness.md`, against the evaluation at 4c4fc6e),
from the model's T = 60 drape (`EvalConfig.oracle_settle_steps`). Cloth has many equilibria, and
the oracle stops at the one its start leads to: started from a drape that settled further (the
model at T = `--steps`), it may stop lower. Per instance: the
reference, the model's drape at T = `--steps` and the oracle from it (the evaluation's oracle
settings, from the record `--eval`), each over the reference. The set's rows GNN only, T = 3 and
T = 15 (as `results/eval.md` gives them: the mean E_total over the references' mean) against the
recorded references and against the lower of each reference and the oracle from the T =
`--steps` drape. One torch thread. Writes <out>.md and <out>.json with the command and the
commit.
"""

from __future__ import annotations

import argparse
import os
import sys

import torch
from eval_record import test_instances
from report import page_head, write_report

from physdrape.checkpoint import load_model
from physdrape.eval import evaluate as ev
from physdrape.eval.config import EvalConfig
from physdrape.model import Variant

#: The set's rows measured against both references: name → solver steps (0: the network's drape).
ROWS = {"gnn_only": 0, "physdrape_t3": 3, "physdrape_t15": 15}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--checkpoint", default="src/physdrape/assets/models/cpu_default")
    parser.add_argument("--steps", type=int, default=60, help="solver steps of the drape the oracle starts from")
    parser.add_argument("--instances", type=int, default=None, help="the first N test instances (default: all)")
    parser.add_argument("--out", default="results/reference_tightness")
    args = parser.parse_args()
    if args.steps < 1:
        raise SystemExit("--steps must be ≥ 1")
    torch.set_num_threads(1)
    instances, references, record = test_instances(args.eval, args.instances)
    settings = record["config"]
    oracle = EvalConfig(oracle_tol=settings["oracle_tol"], oracle_max_iters=settings["oracle_max_iters"],
                        oracle_budget_s=settings["oracle_budget_s"])
    model, _ = load_model(args.checkpoint, variant=Variant.FULL)
    network, _ = load_model(args.checkpoint, variant=Variant.GNN_ONLY)
    contact = ev.Contact.of(model)
    rows = []
    for inst, ref in zip(instances, references):
        batch = inst.batch().drape
        with torch.no_grad():
            out = model(batch, steps=args.steps)
            energies = {name: float(ev.total_energy(ev.run_model(model if steps else network, batch, steps=steps)[0],
                                                    batch, contact)[0]) for name, steps in ROWS.items()}
        start = float(ev.total_energy(out.x, batch, contact)[0])
        result = ev.run_oracle(batch, oracle, contact, out.x)
        polished = float(ev.total_energy(result.x.to(batch.x_init.dtype), batch, contact)[0])
        rows.append({"garment": inst.garment, "category": inst.category, "reference": ref["energy_total"],
                     "reference_source": ref["source"], "start": start, "polished": polished,
                     "reason": result.reason, "wall_s": float(result.wall_time), "rows": energies})
        print(f"[tightness] {inst.garment}: T={args.steps} {start / ref['energy_total']:.4f}, oracle from it "
              f"{polished / ref['energy_total']:.4f} ({result.reason}, {result.wall_time:.0f} s)",
              file=sys.stderr, flush=True)

    recorded = sum(r["reference"] for r in rows)
    lowest = sum(min(r["reference"], r["polished"]) for r in rows)
    summary = {name: {"recorded": sum(r["rows"][name] for r in rows) / recorded,
                      "lowest": sum(r["rows"][name] for r in rows) / lowest} for name in ROWS}
    lower = [r for r in rows if r["polished"] < r["reference"]]
    command, prov, head = page_head("How low the references are: the oracle from the model's longer drape")
    load = os.getloadavg()
    lines = [*head,
             f"Checkpoint `{args.checkpoint}`; {len(rows)} test instances and their references from `{args.eval}` "
             f"(its commit {record['versions']['git_commit'][:7]}); the oracle with the evaluation's settings (tol "
             f"{oracle.oracle_tol}, at most {oracle.oracle_max_iters} iterations and {oracle.oracle_budget_s:g} s) "
             f"from the model's T = {args.steps} drape; one torch thread; load average at the end {load[0]:.2f} "
             f"{load[1]:.2f} {load[2]:.2f}.", "",
             f"The oracle from the T = {args.steps} drape ends below the reference on {len(lower)} of {len(rows)} "
             f"instances; the lower of the two lowers the references' mean by "
             f"{100 * (1 - lowest / recorded):.2f} %.", "",
             "| row | E / recorded reference | E / the lower reference |", "|---|---:|---:|"]
    for name, cell in summary.items():
        lines.append(f"| {name} | {cell['recorded']:.4f} | {cell['lowest']:.4f} |")
    lines += ["", f"Per instance, over its recorded reference: the model's drape at T = {args.steps} (the oracle's "
              "start) and the oracle's end from it.", "",
              f"| instance | category | reference [J] (from) | T = {args.steps} | oracle from it | its end "
              "| wall [s] |",
              "|---|---|---:|---:|---:|---|---:|"]
    for r in rows:
        lines.append(f"| {r['garment']} | {r['category']} | {r['reference']:.4f} ({r['reference_source']}) | "
                     f"{r['start'] / r['reference']:.4f} | {r['polished'] / r['reference']:.4f} | {r['reason']} | "
                     f"{r['wall_s']:.0f} |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "checkpoint": args.checkpoint,
                                   "eval": args.eval, "steps": args.steps, "summary": summary, "rows": rows})


if __name__ == "__main__":
    main()
