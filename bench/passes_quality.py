"""What more network passes buy and what they cost: the test split's E_total over the converged
reference against the solver's steps T and the drape's wall time, for networks making 1 to 4 passes.

Run: .venv/bin/python bench/passes_quality.py [--eval results/eval.json]
     [--checkpoint NAME=DIR ...] [--passes 1 2 3 4] [--steps 1 2 3 5 8 10 12 15] [--instances N]
     [--out results/passes_quality]

A pass (`ModelConfig.passes`) runs the network again at the garment the passes before it moved,
its inputs (the solver's first step among them) found again there; `Draper(passes=...)` and
`physdrape drape --passes` choose it at inference. The instances are the evaluation's test
instances and their references those of the evaluation record `--eval` (per instance the lowest
E_total among its oracle runs that converged, `physdrape.eval.summary.reference`),
so E / ref reads as `results/eval.md` gives it: the set's mean E_total over the references' mean.
Per network (default: the bundled one) and number of passes: the GNN-only drape (X_init plus the
passes' moves) and the model (passes → solver T → handler) at each T, each timed by one call after
a warm-up on the same instance, the networks and passes taking turns at each T so that their
times are measured side by side; wall times are medians over the instances. One torch thread.
Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import torch
from eval_record import test_instances
from report import page_head, write_report

from physdrape.checkpoint import load_model
from physdrape.eval import evaluate as ev
from physdrape.model import Variant


def named(text: str) -> tuple[str, str]:
    """NAME=DIR of a --checkpoint argument (DIR alone: named by its last folder)."""
    name, _, path = text.rpartition("=")
    return (name or os.path.basename(os.path.normpath(path)), path)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record holding the references")
    parser.add_argument("--checkpoint", type=named, action="append",
                        help="NAME=DIR of a network (repeatable; default: bundled=the bundled model)")
    parser.add_argument("--passes", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--steps", type=int, nargs="+", default=[1, 2, 3, 5, 8, 10, 12, 15])
    parser.add_argument("--instances", type=int, default=None, help="the first N test instances (default: all)")
    parser.add_argument("--out", default="results/passes_quality")
    args = parser.parse_args()
    if any(p < 1 for p in args.passes) or any(t < 1 for t in args.steps):
        raise SystemExit("--passes and --steps take integers ≥ 1")
    checkpoints = args.checkpoint or [("bundled", "src/physdrape/assets/models/cpu_default")]
    torch.set_num_threads(1)
    instances, references, record = test_instances(args.eval, args.instances)
    keys = [(name, p) for name, _ in checkpoints for p in args.passes]
    models = {}
    for name, path in checkpoints:
        for p in args.passes:
            models[(name, p)] = {"full": load_model(path, variant=Variant.FULL, passes=p)[0],
                                 "gnn": load_model(path, variant=Variant.GNN_ONLY, passes=p)[0]}
    contact = ev.Contact.of(models[keys[0]]["full"])
    load_start = os.getloadavg()
    rows = []
    for inst, ref in zip(instances, references):
        batch = inst.batch().drape
        row = {"garment": inst.garment, "category": inst.category, "reference": ref["energy_total"],
               "runs": {f"{name}/{p}": {"steps": {}} for name, p in keys}}
        with torch.no_grad():
            for key in keys:
                cell = row["runs"][f"{key[0]}/{key[1]}"]
                cell["gnn_only"] = float(ev.total_energy(models[key]["gnn"](batch).x, batch, contact)[0])
                models[key]["full"](batch, steps=1)  # warm-up: the instance's templates and caches
            for steps in args.steps:
                for key in keys:
                    t0 = time.perf_counter()
                    x = models[key]["full"](batch, steps=steps).x
                    wall = time.perf_counter() - t0
                    cell = {"energy_total": float(ev.total_energy(x, batch, contact)[0]), "wall_s": wall}
                    if steps == max(args.steps):
                        cell["b2g_percent"] = ev._metrics(x, batch, contact)["b2g_percent"]
                    row["runs"][f"{key[0]}/{key[1]}"]["steps"][str(steps)] = cell
        rows.append(row)
        print(f"[passes] {inst.garment}: " + ", ".join(
            f"{k} T={max(args.steps)} {c['steps'][str(max(args.steps))]['energy_total'] / ref['energy_total']:.4f}"
            for k, c in row["runs"].items()), file=sys.stderr, flush=True)
    load_end = os.getloadavg()
    ref_sum = sum(row["reference"] for row in rows)
    summary = {}
    for name, p in keys:
        runs = [row["runs"][f"{name}/{p}"] for row in rows]
        summary[f"{name}/{p}"] = {
            "network": name, "passes": p,
            "gnn_only": sum(r["gnn_only"] for r in runs) / ref_sum,
            "steps": {str(t): {"ratio": sum(r["steps"][str(t)]["energy_total"] for r in runs) / ref_sum,
                               "median_wall_s": float(np.median([r["steps"][str(t)]["wall_s"] for r in runs]))}
                      for t in args.steps},
            "b2g_percent": float(np.mean([r["steps"][str(max(args.steps))]["b2g_percent"] for r in runs]))}
    last = max(args.steps)
    command, prov, head = page_head("More network passes: E_total over the reference against T and wall time")
    lines = [*head,
             f"{len(rows)} test instances and their references from `{args.eval}` (its commit "
             f"{record['versions']['git_commit'][:7]}); networks: "
             + ", ".join(f"{name} = `{path}`" for name, path in checkpoints)
             + f"; one torch thread; load average (1 min) {load_start[0]:.2f} at the start, {load_end[0]:.2f} at the "
             "end.", "",
             "E / ref: the set's mean E_total over the references' mean (as `results/eval.md`). GNN only: X_init "
             "plus the passes' moves. T: the model (passes → solver T → handler); each cell E / ref and the median "
             "wall time of one call over the instances [ms], the runs taking turns at each T.", "",
             "| network | passes | GNN only | " + " | ".join(f"T = {t}" for t in args.steps)
             + f" | B2G at T = {last} [%] |",
             "|---|---:|---:|" + "---:|" * len(args.steps) + "---:|"]
    for key, s in summary.items():
        cells = [f"{s['steps'][str(t)]['ratio']:.4f} ({1e3 * s['steps'][str(t)]['median_wall_s']:.0f} ms)"
                 for t in args.steps]
        lines.append(f"| {s['network']} | {s['passes']} | {s['gnn_only']:.4f} | " + " | ".join(cells)
                     + f" | {s['b2g_percent']:.2f} |")
    shown = sorted({3, last} & set(args.steps))
    lines += ["", "Per category, E / ref of GNN only" + "".join(f", T = {t}" for t in shown) + ":", "",
              "| network | passes | " + " | ".join(sorted({row['category'] for row in rows})) + " |",
              "|---|---:|" + "---|" * len({row['category'] for row in rows})]
    for name, p in keys:
        cells = []
        for category in sorted({row["category"] for row in rows}):
            chosen = [row for row in rows if row["category"] == category]
            ref = sum(row["reference"] for row in chosen)
            runs = [row["runs"][f"{name}/{p}"] for row in chosen]
            parts = [sum(r["gnn_only"] for r in runs) / ref]
            parts += [sum(r["steps"][str(t)]["energy_total"] for r in runs) / ref for t in shown]
            cells.append(" / ".join(f"{v:.4f}" for v in parts))
        lines.append(f"| {name} | {p} | " + " | ".join(cells) + " |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "eval": args.eval,
                                   "checkpoints": dict(checkpoints), "passes": args.passes, "steps": args.steps,
                                   "load_average": {"start": list(load_start), "end": list(load_end)},
                                   "summary": summary, "instances": rows})


if __name__ == "__main__":
    main()
