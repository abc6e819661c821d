"""PhysDrape vs. the physics oracle: wall time per garment, in one run on the same instances.

For each test instance (the evaluation protocol's, `physdrape.eval.evaluate`): the model at T = 3
and T = 15 (median of `--repeats` timed calls after a warm-up, plus the median time of the
kinematic init X_init it starts from), then the oracle from the plain skinned start
(`physdrape.eval.evaluate.InstanceInput.skinned`: PhysDrape's strain-limiting pull-back is part
of the model's timed pipeline, not a head start handed to the oracle),
reporting (a) the time at which the oracle's history first reaches a total energy
(E_strain + E_bend + E_grav + contact penalty) ≤ the model's on that instance and (b) its time to
convergence (tol 1e-2). Where the oracle never gets there its time is a lower bound, marked ≥:
its wall time when it stopped on its budget, and "never" where it converged (a local minimum)
above the model's energy. A median is marked ≥ when a bound lies at or below it (the true
median can only be larger).

    .venv/bin/python bench/bench_speed.py --checkpoint runs/cpu_default --instances 3 --oracle-budget 120
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time

import torch
from timing import median_bound

from physdrape.body.anny_body import get_anny_body
from physdrape.checkpoint import load_model
from physdrape.eval.evaluate import (
    Contact,
    EvalConfig,
    _test_instances,
    run_model,
    run_oracle,
    total_energy,
)
from physdrape.model import Variant


def time_to_energy(history, target: float) -> float:
    """Wall time [s] at which the oracle's energy first is ≤ target (inf if never)."""
    for record in history:
        if record.energy <= target:
            return record.wall
    return math.inf


def fmt_bound(value: float, bound: bool) -> str:
    if math.isinf(value):
        return "never"
    return f"≥{value:.3g}" if bound else f"{value:.3g}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--instances", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--oracle-budget", type=float, default=120.0)
    parser.add_argument("--max-garments", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", help="also write the per-instance numbers here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    config = EvalConfig(instances=args.instances, seed=args.seed, oracle_budget_s=args.oracle_budget,
                        max_garments=args.max_garments, threads=args.threads)
    model, info = load_model(args.checkpoint, variant=Variant.FULL)
    print(f"checkpoint {info['path']} (step {info['step']}); {args.instances} instances, seed {args.seed}, "
          f"oracle budget {args.oracle_budget} s, {args.threads} thread(s), {torch.get_num_threads()} torch threads")
    contact = Contact.of(model)
    instances = _test_instances(config, get_anny_body())
    rows = []
    for inst in instances:
        batch, _, skinned = inst.batch()  # (also the warm-up of the kinematic init)
        row = {"garment": inst.garment, "num_verts": inst.num_verts, "body": inst.body_index}
        row["init_s"] = statistics.median(inst.batch()[1] for _ in range(args.repeats))
        for steps in (3, 15):
            run_model(model, batch, steps=steps)  # warm-up
            times, x = [], None
            for _ in range(args.repeats):
                x, wall = run_model(model, batch, steps=steps)
                times.append(wall)
            row[f"model_t{steps}_s"] = row["init_s"] + statistics.median(times)  # X_init + model, as a user pays
            row[f"model_t{steps}_energy"] = float(total_energy(x, batch, contact)[0])
        t0 = time.perf_counter()
        result = run_oracle(batch, config, contact, skinned)
        row["oracle_wall_s"] = time.perf_counter() - t0
        row["oracle_converged"] = bool(result.converged)
        row["oracle_reason"] = result.reason
        row["oracle_energy"] = float(result.energy_terms["total"].sum())
        row["oracle_to_converged_s"] = result.wall_time  # a lower bound unless converged
        for steps in (3, 15):
            reached = time_to_energy(result.history, row[f"model_t{steps}_energy"])
            row[f"oracle_reached_t{steps}"] = math.isfinite(reached)
            # not reached: at least its wall time (budget), or never (it converged above the model)
            row[f"oracle_to_t{steps}_energy_s"] = (reached if math.isfinite(reached)
                                                   else math.inf if result.converged else result.wall_time)
        rows.append(row)
        print(json.dumps(row), file=sys.stderr)  # (Infinity: never reached)

    def med(key):
        return statistics.median(r[key] for r in rows)

    n = len(rows)
    print()
    print(f"| (medians over {n} instances) | T=3 | T=15 |")
    print("|---|---|---|")
    print(f"| of which X_init (skinning + strain limiting) [s] | {med('init_s'):.3g} | {med('init_s'):.3g} |")
    print(f"| model wall / garment, X_init included [s] | {med('model_t3_s'):.3g} | {med('model_t15_s'):.3g} |")
    print(f"| model E_total [J] | {med('model_t3_energy'):.4g} | {med('model_t15_energy'):.4g} |")
    print(f"| oracle E_total at its end [J] | {med('oracle_energy'):.4g} | {med('oracle_energy'):.4g} |")
    cells = {}
    for steps in (3, 15):
        reached = [r[f"oracle_reached_t{steps}"] for r in rows]
        never = sum(1 for r in rows if math.isinf(r[f"oracle_to_t{steps}_energy_s"]))
        cells[f"reached{steps}"] = f"{sum(reached)}/{n} (never: {never}, converged above it)"
        times = [r[f"oracle_to_t{steps}_energy_s"] for r in rows]
        cells[f"time{steps}"] = fmt_bound(*median_bound(times, [not b for b in reached]))
        ratios = [t / r[f"model_t{steps}_s"] for t, r in zip(times, rows)]
        for r, ratio in zip(rows, ratios):
            r[f"ratio_energy_t{steps}"] = ratio
        cells[f"ratio{steps}"] = fmt_bound(*median_bound(ratios, [not b for b in reached]))
        conv = [r["oracle_to_converged_s"] / r[f"model_t{steps}_s"] for r in rows]
        for r, ratio in zip(rows, conv):
            r[f"ratio_converged_t{steps}"] = ratio
        cells[f"conv{steps}"] = fmt_bound(*median_bound(conv, [not r["oracle_converged"] for r in rows]))
    print(f"| oracle reached the model's energy on | {cells['reached3']} | {cells['reached15']} |")
    print(f"| oracle time to the model's energy [s] | {cells['time3']} | {cells['time15']} |")
    conv_s = fmt_bound(*median_bound([r["oracle_to_converged_s"] for r in rows], [not r["oracle_converged"] for r in rows]))
    print(f"| oracle time to convergence [s] ({sum(r['oracle_converged'] for r in rows)}/{n} converged) "
          f"| {conv_s} | {conv_s} |")
    print(f"| median ratio: oracle to the model's energy / model | {cells['ratio3']} | {cells['ratio15']} |")
    print(f"| median ratio: oracle to convergence / model | {cells['conv3']} | {cells['conv15']} |")
    if args.json:
        with open(args.json, "w") as handle:
            finite = [{k: (None if isinstance(v, float) and math.isinf(v) else v) for k, v in r.items()} for r in rows]
            json.dump({"checkpoint": info, "config": vars(args), "instances": finite,
                       "note": "null times: the oracle converged above the model's energy (never reached)"}, handle, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
