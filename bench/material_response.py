"""Material response: how much of the physical difference between fabrics the fast drape reproduces.

Run: .venv/bin/python bench/material_response.py [--garments default longsleeve:0] [--steps 15]
     [--long-steps 200] [--oracle-budget 120] [--oracle-max-iters 1000] [--threads 1]
     [--out results/material_response] [--figures]

For each garment (the bundled T-shirt, a generated long-sleeve top) on the default body (Anny, all
phenotypes 0.5, the default pose) and each material preset (`physics.presets`, silk … leather),
measured on the same X_init:

- ``fast``: the product's default drape, `Draper.drape` with T = --steps (network, two-level
  solver, collision handler), in the API's default dtype;
- ``gnn_only``: X_init + Δx, the network's displacement alone;
- ``no_network``: the same solver and handler from X_init with Δx = 0 and f̂ = 0, T = --steps;
- ``long``: the full model with T = --long-steps solver steps (where the few-step solver heads);
- ``oracle``: `physics.relax` (projected Newton, penalty contact) from the fast drape to its
  tolerance: what ``drape --refine`` does, the physics' own answer near that drape;
- ``oracle_init``: `physics.relax` from X_init (the oracle is a local minimiser; a second start
  shows whether the physics' answer depends on where it starts).

Measures (each row, float64, the definitions are also written into the output files):
hem drop and its spread (`physdrape.render.hem`: the garment's longest opening, the mean and the
standard deviation of y_init − y over its vertices), E_bend and E_strain as the drape metrics
(`physics.metrics`: default-material constants for every fabric, so they compare shapes) and with
the preset's own constants, E_total (strain + bend + gravity + contact penalty, the preset's
constants: what the oracle minimises), settled % = share of the energy drop from X_init to the
lower of the two oracle results that the row achieves, and B2G %.

Writes <out>.json and <out>.md atomically, each naming the command and the git commit; with
--figures also <out>_<garment>_{fast,oracle}.png (the material sweep figure of both).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from physdrape.api import Draper
from physdrape.atomic import write_text
from physdrape.eval.evaluate import Contact, total_energy
from physdrape.eval.report import finite_or_none
from physdrape.physics import energy_terms, relax
from physdrape.physics.metrics import drape_metrics
from physdrape.physics.oracle import silenced
from physdrape.physics.presets import MATERIAL_PRESETS, material_preset
from physdrape.pipeline import POSE_DTYPE, DrapePipeline, Job
from physdrape.provenance import provenance
from physdrape.render import material_sweep_figure
from physdrape.render.hem import hem_drop, hem_loop

ROWS = ("gnn_only", "fast", "no_network", "long", "oracle", "oracle_init")
DEFINITIONS = {
    "hem": "the garment's longest opening: the boundary loop with the largest perimeter at X_init (a top's waist opening)",
    "hem_drop_cm": "mean over the hem's vertices of y_init - y [cm]: how far the hem hangs below where the skinned "
                   "garment (X_init, before any physics) put it; positive = lower",
    "hem_spread_cm": "standard deviation of that drop over the hem's vertices [cm] (ripples and tilt of the hem)",
    "E_bend_J, E_strain_J": "the drape metrics (physics.metrics): energies with the default (cotton) constants for "
                            "every fabric, so they compare the shapes",
    "E_bend_own_J, E_strain_own_J": "the same energies with the preset's own constants",
    "E_total_J": "E_strain + E_bend + E_grav + contact penalty with the preset's own constants (what the oracle minimises)",
    "settled_percent": "100 (E_total(X_init) - E_total(row)) / (E_total(X_init) - E_total(reference)), reference = the "
                       "lower-energy of the two oracle rows",
    "b2g_percent": "body-to-garment interpenetration, area share of faces whose centroid is inside the body [%]",
}


def measure(x: torch.Tensor, ref, hem: np.ndarray, contact: Contact) -> dict[str, float]:
    """The measures of drape x (V, 3) of one garment on the float64 problem `ref` (a DrapeInput)."""
    x = x.to(torch.float64)
    metrics = drape_metrics(x, ref.garments, ref.bodies, ref.body_index, cloth=ref.cloth)
    own = energy_terms(x, ref.cloth)
    drop = hem_drop(x.numpy(), ref.x_init.numpy(), hem)
    return {"hem_drop_cm": 100 * drop.mean, "hem_spread_cm": 100 * drop.spread,
            "E_bend_J": float(metrics.bend[0]), "E_strain_J": float(metrics.strain[0]),
            "E_bend_own_J": float(own["bend"][0]), "E_strain_own_J": float(own["strain"][0]),
            "E_total_J": float(total_energy(x, ref, contact)[0]), "b2g_percent": float(metrics.b2g_percent[0])}


def oracle(start: torch.Tensor, ref, contact: Contact, args) -> tuple[torch.Tensor, dict]:
    """`relax` from `start` on the float64 problem `ref`: (x, how it ended)."""
    with silenced(1):
        res = relax(start.to(torch.float64), ref.cloth, ref.bodies, torch.zeros(1, dtype=torch.int64),
                    contact="penalty", tol=args.oracle_tol, max_iters=args.oracle_max_iters,
                    time_budget_s=args.oracle_budget, contact_stiffness=contact.stiffness, margin=contact.margin)
    return res.x, {"converged": bool(res.converged), "reason": res.reason, "iterations": len(res.history) - 1,
                   "wall_s": float(res.wall_time)}


def run_garment(spec: str, names: list[str], draper: Draper, state, pipe64: DrapePipeline, contact: Contact, args):
    """Every row and measure of garment `spec` in each material of `names`; also the fast and oracle
    drapes as `DrapeResult`s (for the figures)."""
    materials = [material_preset(n) for n in names]
    template = draper.garment(spec)
    t0 = time.perf_counter()
    fast = draper.drape(spec, material=materials)
    fast_s = (time.perf_counter() - t0) / len(materials)
    inp = draper.pipeline("anny").build([Job(template, 0, m) for m in materials], state)
    with torch.no_grad():
        out = draper.model(inp, steps=args.steps)
        xs = {"gnn_only": inp.garments.split(out.x_gnn),
              "no_network": inp.garments.split(draper.model.physics_only(inp, steps=args.steps).x),
              "long": inp.garments.split(draper.model(inp, steps=args.long_steps).x)}
    same = max(float(np.abs(a.numpy() - r.verts).max()) for a, r in zip(inp.garments.split(out.x), fast))
    rows, oracle_results = [], []
    for k, (name, material) in enumerate(zip(names, materials)):
        ref = pipe64.build([Job(template, 0, material)], state)
        hem = hem_loop(template.faces, ref.x_init.numpy())
        drapes = {"fast": torch.from_numpy(fast[k].verts), **{row: x[k] for row, x in xs.items()}}
        x_oracle, oracle_end = oracle(drapes["fast"], ref, contact, args)
        x_init_oracle, init_end = oracle(ref.x_init, ref, contact, args)
        drapes.update(oracle=x_oracle, oracle_init=x_init_oracle)
        values = {row: measure(drapes[row], ref, hem, contact) for row in ROWS}
        start = measure(ref.x_init, ref, hem, contact)
        target = min(values["oracle"]["E_total_J"], values["oracle_init"]["E_total_J"])
        for row in ROWS:
            gain = start["E_total_J"] - target
            values[row]["settled_percent"] = 100 * (start["E_total_J"] - values[row]["E_total_J"]) / gain if gain > 0 else math.nan
        values["fast"]["wall_s"] = fast_s
        values["oracle"].update(oracle_end)
        values["oracle_init"].update(init_end)
        rows.append({"garment": template.name, "material": name, "num_verts": int(template.num_verts),
                     "hem_num_verts": len(hem), "x_init": start, **values})
        metrics = drape_metrics(x_oracle, ref.garments, ref.bodies, ref.body_index, cloth=ref.cloth).as_dict()
        oracle_results.append(replace(fast[k], verts=x_oracle.to(torch.float32).numpy(),
                                      metrics={key: v[0] for key, v in metrics.items()}))
        print(f"{template.name} {name}: fast hem drop {values['fast']['hem_drop_cm']:.2f} cm, oracle "
              f"{values['oracle']['hem_drop_cm']:.2f} cm ({oracle_end['reason']}, {oracle_end['wall_s']:.0f} s)",
              file=sys.stderr, flush=True)
    return rows, fast, oracle_results, same


def _f(value, digits: int = 3) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        return "–"
    return f"{value:.{digits}g}" if isinstance(value, float) else str(value)


def markdown(record: dict) -> str:
    """The record as Markdown: per garment a headline table (fast vs oracle) and a table of every row."""
    cfg = record["config"]
    out = ["# Material response: the fast drape vs the physics oracle, per fabric preset", "",
           f"Command: `{record['command']}`  ", f"Git commit: `{record['provenance']['git_commit']}`"
           + (" (with uncommitted changes)" if record["provenance"]["git_dirty"] else ""), "",
           f"Default body (Anny, phenotypes 0.5, pose `{record['pose']}`); fast = `Draper.drape`, T = {cfg['steps']}; "
           f"oracle = `physics.relax` from the fast drape (= `drape --refine`), tol {cfg['oracle_tol']}, "
           f"{cfg['oracle_budget']:g} s / {cfg['oracle_max_iters']} iterations per drape; torch threads {cfg['threads']}.",
           "", "Definitions:", ""]
    out += [f"- **{k}**: {v}" for k, v in record["definitions"].items()]
    for garment, rows in record["garments"].items():
        first, last = rows[0], rows[-1]
        out += ["", f"## {garment} ({first['num_verts']} vertices, hem of {first['hem_num_verts']})", "",
                "| material | hem drop fast [cm] | hem drop oracle [cm] | E_bend fast [J] | E_bend oracle [J] "
                "| E_strain fast [J] | E_strain oracle [J] | B2G fast [%] | B2G oracle [%] | settled fast [%] |",
                "|---|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            f, o = r["fast"], r["oracle"]
            out.append(f"| {r['material']} | {f['hem_drop_cm']:.2f} | {o['hem_drop_cm']:.2f} | {_f(f['E_bend_J'])} "
                       f"| {_f(o['E_bend_J'])} | {_f(f['E_strain_J'])} | {_f(o['E_strain_J'])} | {f['b2g_percent']:.2f} "
                       f"| {o['b2g_percent']:.2f} | {f['settled_percent']:.0f} |")
        out += ["", f"{first['material']} vs {last['material']}:"]
        for row in ("fast", "oracle", "oracle_init"):
            a, b = first[row], last[row]
            out.append(f"- {row}: hem drop {a['hem_drop_cm'] - b['hem_drop_cm']:+.2f} cm "
                       f"({first['material']} − {last['material']}); E_bend ratio {a['E_bend_J'] / b['E_bend_J']:.2f}; "
                       f"hem spread {a['hem_spread_cm']:.2f} vs {b['hem_spread_cm']:.2f} cm")
        out += ["", "| material | row | hem drop [cm] | spread [cm] | E_bend [J] | E_strain [J] | E_bend own [J] "
                "| E_strain own [J] | E_total [J] | settled [%] | B2G [%] | oracle end |", "|---" * 12 + "|"]
        for r in rows:
            for row in ("x_init", *ROWS):
                v = r[row]
                end = f"{v['reason']}, {v['iterations']} it, {v['wall_s']:.0f} s" if "reason" in v else ""
                out.append(f"| {r['material']} | {row} | {v['hem_drop_cm']:.2f} | {v['hem_spread_cm']:.2f} "
                           f"| {_f(v['E_bend_J'])} | {_f(v['E_strain_J'])} | {_f(v['E_bend_own_J'])} "
                           f"| {_f(v['E_strain_own_J'])} | {v['E_total_J']:.5g} "
                           f"| {_f(v.get('settled_percent', 0.0), 3)} | {v['b2g_percent']:.2f} | {end} |")
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--garments", nargs="+", default=["default", "longsleeve:0"])
    parser.add_argument("--materials", nargs="+", default=list(MATERIAL_PRESETS))
    parser.add_argument("--steps", type=int, default=15, help="the fast drape's solver steps T")
    parser.add_argument("--long-steps", type=int, default=200, help="solver steps of the 'long' row")
    parser.add_argument("--oracle-budget", type=float, default=120.0, help="wall-time budget per oracle run [s]")
    parser.add_argument("--oracle-max-iters", type=int, default=1000)
    parser.add_argument("--oracle-tol", type=float, default=1e-2, help="residual tolerance (per vertex weight)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="results/material_response", help="writes OUT.json and OUT.md")
    parser.add_argument("--figures", action="store_true", help="also the material sweep of the fast and oracle drapes")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    command = "python " + shlex.join(sys.argv if argv is None else ["bench/material_response.py", *argv])
    draper = Draper(steps=args.steps)
    body = draper.body("anny")
    [pose] = draper.poses(None)
    state = body(draper.shape(None).to(POSE_DTYPE), pose.pose.to(POSE_DTYPE))
    pipe64 = DrapePipeline(body, dtype=torch.float64)
    contact = Contact(draper.model_config.contact_stiffness, draper.model_config.margin)
    out = Path(args.out)
    record = {"command": command, "provenance": provenance(), "config": vars(args), "pose": pose.label,
              "checkpoint": str(draper.checkpoint), "definitions": DEFINITIONS, "garments": {}, "fast_vs_model_max_m": {}}
    for spec in args.garments:
        rows, fast, oracle_results, same = run_garment(spec, args.materials, draper, state, pipe64, contact, args)
        record["garments"][rows[0]["garment"]] = rows
        record["fast_vs_model_max_m"][rows[0]["garment"]] = same
        if args.figures:
            stem = f"{out.name}_{rows[0]['garment']}"
            material_sweep_figure(fast, args.materials, out.parent / f"{stem}_fast.png",
                                  note=f"fast drape (T = {args.steps})")
            material_sweep_figure(oracle_results, args.materials, out.parent / f"{stem}_oracle.png",
                                  note="oracle (relax from the fast drape)")
    text = markdown(record)
    write_text(out.with_suffix(".json"), json.dumps(finite_or_none(record), indent=1, allow_nan=False, default=str) + "\n")
    write_text(out.with_suffix(".md"), text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
