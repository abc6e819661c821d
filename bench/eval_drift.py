"""How far the model's energies on the test instances have moved since `results/eval.json` was written.

    .venv/bin/python bench/eval_drift.py [--eval results/eval.json] [--checkpoint DIR] [--[no-]follow-planes]
        [--makehuman ../shared/data/makehuman_cc0] [--out results/eval_drift]

Reruns the model rows of the evaluation (GNN only, PhysDrape at T = 3 and T = 15, and the solver
alone at T = 3 and T = 15) on the evaluation's test instances with the bundled model (or
`--checkpoint`, a model trained since), and divides their mean E_total by the per-instance
references recorded in the eval file: the same ratios as `eval.md`'s "E_total / reference"
column, without rerunning the oracle (about an hour), the mean B2G % beside the recorded one,
and the mean E_strain over the references' (as `eval.md`'s E_strain ratio). A row the eval
file lacks shows its values now only. A change that should leave the drape's physics alone
(a faster kernel, a cache) is checked this way; a change of the physics needs the full
`physdrape eval`. With `--makehuman DIR` the MakeHuman suits of the eval file (worn as the
evaluation wears them) are compared the same way, in a table of their own. Writes <out>.md and
<out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import sys
from pathlib import Path

import torch
from eval_record import suit_instances
from report import source_lines, write_report

from physdrape.body.anny_body import get_anny_body
from physdrape.checkpoint import bundled_model, load_model
from physdrape.eval.config import EvalConfig
from physdrape.eval.evaluate import Contact, run_model, total_energy
from physdrape.eval.instances import split_instances
from physdrape.model.config import Variant
from physdrape.physics.metrics import b2g_percent
from physdrape.physics.strain import strain_energy
from physdrape.provenance import provenance

#: eval.json row → (variant, solver steps, with the network)
ROWS = {"gnn_only": (Variant.GNN_ONLY, None, True), "physdrape_t3": (Variant.FULL, 3, True),
        "physdrape_t15": (Variant.FULL, 15, True), "physics_only_t3": (Variant.FULL, 3, False),
        "physics_only": (Variant.FULL, 15, False)}


def _planes_note(solver, override: bool | None) -> str:
    every, follow = solver.planes_schedule()
    held = (f"followed (found again after a {1e3 * solver.follow_min_move:g} mm move)" if follow and solver.follow_min_move
            else "followed at every step" if follow else "held")
    flag = "" if override is None else f" (`--{'' if override else 'no-'}follow-planes`)"
    return f", the solver's body planes {held} between body queries every {every} steps{flag}"


def _drift(recorded_set: dict, instances: list, models: dict) -> tuple[list[dict], dict]:
    """(rows, per-instance values) of one set of the eval file: the model rows run again on its
    instances, against the set's recorded rows and references."""
    reference = [r["energy_total"] for r in recorded_set["reference"]["per_instance"]]
    rows_in = recorded_set["rows"]
    recorded = {row: [r["energy_total"] for r in rows_in[row]["per_instance"]] for row in ROWS if row in rows_in}
    recorded_b2g = {row: [r["b2g_percent"] for r in rows_in[row]["per_instance"]] for row in recorded}
    reference_strain = [r["strain"] for r in recorded_set["reference"]["per_instance"]]
    recorded_strain = {row: [r["strain"] for r in rows_in[row]["per_instance"]] for row in recorded}
    contact = Contact.of(models[Variant.FULL])
    now = {row: [] for row in ROWS}
    b2g = {row: [] for row in ROWS}
    strain = {row: [] for row in ROWS}
    wall = {row: [] for row in ROWS}
    for instance in instances:
        batch = instance.batch().drape
        for row, (variant, steps, network) in ROWS.items():
            x, seconds = run_model(models[variant], batch, steps=steps, network=network)
            now[row].append(float(total_energy(x, batch, contact)[0]))
            b2g[row].append(float(b2g_percent(x, batch.garments, batch.bodies, batch.body_index)[0]))
            strain[row].append(float(strain_energy(x, batch.cloth).sum()))  # one garment per batch
            wall[row].append(seconds)
    rows = []
    for row in ROWS:
        after = sum(now[row]) / sum(reference)
        before = sum(recorded[row]) / sum(reference) if row in recorded else None  # a row the eval file lacks
        worst = max(abs(a / b - 1.0) for a, b in zip(now[row], recorded[row])) if row in recorded else None
        rows.append({"row": row, "ratio_recorded": before, "ratio_now": after,
                     "change": None if before is None else after / before - 1.0,
                     "largest_instance_change": worst, "model_wall_median_s": statistics.median(wall[row]),
                     "b2g_percent_recorded": statistics.mean(recorded_b2g[row]) if row in recorded else None,
                     "b2g_percent_now": statistics.mean(b2g[row]),
                     "strain_ratio_recorded": (sum(recorded_strain[row]) / sum(reference_strain)
                                               if row in recorded else None),
                     "strain_ratio_now": sum(strain[row]) / sum(reference_strain)})
    per_instance = {"reference": reference, "recorded": recorded, "now": now, "b2g_percent_recorded": recorded_b2g,
                    "b2g_percent_now": b2g, "reference_strain": reference_strain, "strain_recorded": recorded_strain,
                    "strain_now": strain}
    return rows, per_instance


def _table(rows: list[dict]) -> list[str]:
    lines = ["| row | E_total / reference, recorded | now | change | largest change of one instance "
             "| B2G % (mean), recorded | now | E_strain / reference's, recorded | now |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if r["ratio_recorded"] is None:
            lines.append(f"| {r['row']} | – | {r['ratio_now']:.4f} | – | – | – | {r['b2g_percent_now']:.2f} | – | "
                         f"{r['strain_ratio_now']:.3f} |")
            continue
        lines.append(f"| {r['row']} | {r['ratio_recorded']:.4f} | {r['ratio_now']:.4f} | {100 * r['change']:+.2f} % | "
                     f"{100 * r['largest_instance_change']:.2f} % | {r['b2g_percent_recorded']:.2f} | "
                     f"{r['b2g_percent_now']:.2f} | {r['strain_ratio_recorded']:.3f} | {r['strain_ratio_now']:.3f} |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record to compare with")
    parser.add_argument("--checkpoint", default="", help="the model to run (default: the bundled one)")
    parser.add_argument("--makehuman", default="", help="also the eval file's MakeHuman suits, read from this folder")
    parser.add_argument("--out", default="results/eval_drift")
    parser.add_argument("--follow-planes", action=argparse.BooleanOptionalAction,
                        help="the solver's body planes followed at every step, or held between body queries "
                             "(`Draper(follow_planes=...)`; default: the checkpoint's)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with open(args.eval) as handle:
        record = json.load(handle)
    config = EvalConfig(**{k: v for k, v in record["config"].items() if k in EvalConfig.__dataclass_fields__})
    instances = split_instances(config, get_anny_body())
    if len(instances) != len(record["sets"]["test"]["reference"]["per_instance"]):
        sys.exit(f"{args.eval} has {len(record['sets']['test']['reference']['per_instance'])} test instances but "
                 f"its config gives {len(instances)} here: the garment split or the config differ; rerun "
                 "`physdrape eval` instead")
    sets = {"test": instances}
    if args.makehuman:
        sets["makehuman"] = suit_instances(args.eval, args.makehuman)[0]
    checkpoint = Path(args.checkpoint or bundled_model()).resolve()
    if checkpoint.is_relative_to(Path.cwd()):
        checkpoint = checkpoint.relative_to(Path.cwd())  # a path inside the repository names no machine
    models = {variant: load_model(checkpoint, variant=variant)[0].eval() for variant in {v for v, _, _ in ROWS.values()}}
    if args.follow_planes is not None:
        for model in models.values():
            model.set_eval_planes(args.follow_planes)
    found = {name: _drift(record["sets"][name], todo, models) for name, todo in sets.items()}
    command = shlex.join(["python", *sys.argv])
    rows, per_instance = found["test"]
    out = {"command": command, "provenance": provenance(), "eval_file": args.eval, "checkpoint": str(checkpoint),
           "eval_commit": record["versions"].get("git_commit"),
           "load_average": os.getloadavg(), "instances": len(instances), "rows": rows, "per_instance": per_instance}
    if "makehuman" in found:
        out["makehuman"] = {"instances": len(sets["makehuman"]), "rows": found["makehuman"][0],
                            "per_instance": found["makehuman"][1]}
    lines = ["# The model's energies on the test instances against those recorded in the evaluation", "",
             *source_lines(command, out["provenance"]),
             f"Compared with `{args.eval}` (written at commit `{out['eval_commit']}`), {len(instances)} test "
             f"instances{' and the MakeHuman suits' if 'makehuman' in found else ''}, its references; model "
             f"`{checkpoint}`"
             + _planes_note(models[Variant.FULL].solver, args.follow_planes)
             + "; 1 torch thread; load average "
             + ", ".join(f"{v:.2f}" for v in out["load_average"]), ""]
    for name, title in (("test", "Test instances"), ("makehuman", "MakeHuman suits")):
        if name not in found:
            continue
        if len(found) > 1:
            lines += [f"## {title} ({len(sets[name])})", ""]
        lines += _table(found[name][0]) + [""]
    write_report(args.out, lines, out)


if __name__ == "__main__":
    main()
