"""Time to quality: E_total over the converged reference against wall time, for the model, its solver alone, the oracle and Newton's VBD, in one run on the same instances.

Instances: the evaluation's test instances (`physdrape.eval.instances.split_instances`), the
first `--instances`. Per instance, on one torch thread by default:

- **model**: the full model (GNN → solver T → collision handler) at every T of `--steps`
  (default 1…15); a point is (X_init + model wall time, E_total of the drape), the model time
  being the median of `--repeats` timed calls after a warm-up and X_init's the median of as many
  builds (`InstanceInput.init_s`), as a user pays (the same accounting as `bench/bench_speed.py`);
  with `--compile` its network compiled by `torch.compile` (`Draper(compile_network=True)`'s;
  compiled by its first warm-up call, outside the timing);
- **solver alone**: `PhysDrape.physics_only` at the same T (Δx = 0, f̂ = 0, then the handler),
  timed the same way;
- **oracle**: `physdrape.eval.evaluate.run_oracle` (`physics.relax`, projected Newton, penalty
  contact) from the plain skinned start (`InstanceInput.skinned`), with the evaluation's settings
  (`--oracle-budget`, `--oracle-max-iters`); its per-iteration history gives the points (wall
  seconds since the start of `relax`, energy);
- **VBD**: Newton's vertex block descent, as `bench/bench_vbd.py` runs it (`VBDSim`, `simulate`,
  with that script's settings; extra settings through `--vbd-args`), from the skinned start; the
  points are its energy checks (wall time excluding its setup and the checks). Needs the optional
  package `newton` (`.venv/bin/pip install newton==1.8.0`); without it the curve is skipped
  and the files say so.

Energies are `physdrape.eval.evaluate.total_energy` (E_strain + E_bend + E_grav + contact penalty
at vertices and face centroids: what the oracle minimises). The **reference** of an instance is the
lowest E_total of the converged oracle results at hand, as in `physdrape eval`: the oracle from the
skinned start (this run's, and the evaluation's cached result from the same start under the
evaluation's settings, `physdrape.eval.reference_cache`, when there is one), the oracle
refining the model's drape at its largest T and the oracle from the model's drape at
`--settle-steps` (60, `EvalConfig.oracle_settle_steps`: a drape settled longer, from which the
oracle can end in a lower equilibrium) (both run here; `--no-refine` leaves them out, the
reference is then the oracle's alone and can lie above the model's drapes).

Headline: per instance the smallest T at which the model is within `--tolerance` (2.5 %) of the
reference, its wall time there, and the times the oracle and VBD take to reach the energy the
model reached there (first point at or below it), as ratios over the model's time; medians over
instances. A method that does not get there is a bound: "≥ its wall time" when it stopped on its
budget, "never" when it converged or settled above it (a median is a bound when a bound lies at
or below it, as in `bench/bench_speed.py`).

Writes `<out>/time_to_quality.json` (per instance, per method: the points as [wall s, E_total J,
E / reference]), `.md` (the tables) and `.png` (E / reference − 1 against wall time, both on log
axes, one panel per instance), each naming the command, the git commit, the load average, the torch
threads and the date.

    .venv/bin/python bench/time_to_quality.py --instances 5 --repeats 3 --threads 1
    .venv/bin/python bench/time_to_quality.py --quick --out /tmp/ttq   # one instance, small budgets
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import importlib.util
import json
import math
import os
import shlex
import statistics
import sys
import time
from pathlib import Path

import torch
from bench_speed import fmt_bound
from timing import median_bound

from physdrape.body.anny_body import get_anny_body
from physdrape.checkpoint import bundled_model, load_model
from physdrape.eval.config import EvalConfig, default_reference_cache
from physdrape.eval.evaluate import (
    Contact,
    oracle_settings,
    run_model,
    run_oracle,
    total_energy,
)
from physdrape.eval.instances import split_instances
from physdrape.eval.reference_cache import ReferenceCache, reference_key
from physdrape.eval.report import finite_or_none
from physdrape.eval.summary import lowest_converged
from physdrape.model import Variant
from physdrape.physics import Material
from physdrape.provenance import provenance

#: The methods, in table and plot order: (key, label).
METHODS = (("model", "PhysDrape (GNN + solver + handler)"), ("solver", "solver alone (physics_only)"),
           ("oracle", "oracle (relax, from skinned)"), ("vbd", "Newton VBD (from skinned)"))
VBD_INSTALL = ".venv/bin/pip install newton==1.8.0"


def parse_steps(text: str) -> list[int]:
    """Solver steps from "1-15" or "1,3,15" (mixed allowed), sorted and unique."""
    out = set()
    for part in text.split(","):
        lo, sep, hi = part.partition("-")
        out.update(range(int(lo), int(hi) + 1) if sep else [int(lo)])
    if not out or min(out) < 1:
        raise argparse.ArgumentTypeError(f"steps must be ≥ 1, got {text!r}")
    return sorted(out)


def vbd_settings(extra: list[str]):
    """`bench/bench_vbd.py`'s VBD settings (its flags and defaults, `extra` flags applied), or None
    with the reason when `newton` is not installed."""
    if importlib.util.find_spec("newton") is None:
        return None, f"`newton` is not installed (`{VBD_INSTALL}`): the VBD curve is skipped"
    import bench_vbd

    settings = bench_vbd.build_parser().parse_args(extra)
    import newton
    import warp as wp

    wp.config.quiet = True
    wp.init()
    wp.set_device("cpu")
    return settings, f"newton {newton.__version__}, warp {wp.__version__}, CPU"


def timed_model(model, batch, steps: int, repeats: int, *, network: bool) -> tuple[float, torch.Tensor]:
    """(median wall seconds of `repeats` calls after a warm-up, the drape)."""
    run_model(model, batch, steps=steps, network=network)
    times, x = [], None
    for _ in range(repeats):
        x, wall = run_model(model, batch, steps=steps, network=network)
        times.append(wall)
    return statistics.median(times), x


def first_reach(points: list[list[float]], target: float) -> float:
    """Wall time [s] of the first point with energy ≤ target (inf: none)."""
    return next((p[0] for p in points if p[1] <= target), math.inf)


def instance_run(inst, model, contact, args, eval_config: EvalConfig, cache: ReferenceCache | None, vbd) -> dict:
    """Every method's points on one instance, the reference and the headline numbers."""
    batch, _, skinned = inst.batch()  # (also the warm-up of the kinematic init)
    init_s = statistics.median(inst.batch()[1] for _ in range(args.repeats))
    row = {"garment": inst.garment, "num_verts": inst.num_verts, "body": inst.body_index, "init_s": init_s,
           "skinned_energy": float(total_energy(skinned, batch, contact)[0]),
           "x_init_energy": float(total_energy(batch.x_init, batch, contact)[0]), "methods": {}}
    candidates = {}  # per oracle run: {"energy_total", "converged"}
    x_last = None
    for key, network in (("model", True), ("solver", False)):
        points, steps_of = [], []
        for steps in args.steps:
            wall, x = timed_model(model, batch, steps, args.repeats, network=network)
            points.append([init_s + wall, float(total_energy(x, batch, contact)[0])])
            steps_of.append(steps)
            if network:
                x_last = x
        row["methods"][key] = {"steps": steps_of, "points": points}
    log(f"  model/solver done ({row['methods']['model']['points'][-1][0]:.3g} s at T = {args.steps[-1]})")

    t0 = time.perf_counter()
    result = run_oracle(batch, args.oracle_config, contact, skinned)
    row["methods"]["oracle"] = {
        "points": [[h.wall, h.energy] for h in result.history], "converged": bool(result.converged),
        "reason": result.reason, "wall_s": time.perf_counter() - t0}
    candidates["oracle"] = candidate(result.x, result.converged, batch, contact)
    log(f"  oracle: {result.reason} in {result.wall_time:.1f} s")
    if cache is not None:
        hit = cache.load(reference_key(batch, skinned, oracle_settings(eval_config, contact)), skinned.shape[0])
        if hit is not None:
            candidates["oracle_cached"] = candidate(hit[0], hit[1].get("converged", True), batch, contact)
    if args.refine and x_last is not None:
        refined = run_oracle(batch, args.oracle_config, contact, x_last)
        candidates["oracle_refined"] = candidate(refined.x, refined.converged, batch, contact)
        row["refined"] = {"converged": bool(refined.converged), "reason": refined.reason,
                          "wall_s": refined.wall_time}
        log(f"  oracle refining the T = {args.steps[-1]} drape: {refined.reason} in {refined.wall_time:.1f} s")
    if args.refine and args.settle_steps:
        with torch.no_grad():
            settled = run_oracle(batch, args.oracle_config, contact, model(batch, steps=args.settle_steps).x)
        candidates["oracle_settled"] = candidate(settled.x, settled.converged, batch, contact)
        row["settled"] = {"converged": bool(settled.converged), "reason": settled.reason,
                          "wall_s": settled.wall_time}
        log(f"  oracle from the T = {args.settle_steps} drape: {settled.reason} in {settled.wall_time:.1f} s")

    if vbd is not None:
        import bench_vbd

        out = bench_vbd.simulate(dataclasses.replace(batch, x_init=skinned), vbd, Material(), -math.inf, contact)
        settled = out["vbd_reason"].startswith("settled")
        row["methods"]["vbd"] = {"points": [[h["wall"], h["energy"]] for h in out["vbd_history"]],
                                 "converged": settled, "reason": out["vbd_reason"], "wall_s": out["vbd_wall_s"],
                                 "setup_s": out["vbd_setup_s"], "sim_s": out["vbd_sim_s"]}
        log(f"  VBD: {out['vbd_reason']} after {out['vbd_wall_s']:.1f} s")

    source, chosen = lowest_converged(list(candidates.items()))
    ref = chosen["energy_total"]
    row["reference"] = {"energy_total": ref, "source": source, "candidates": candidates}
    for method in row["methods"].values():
        for p in method["points"]:
            p.append(p[1] / ref)
    row["headline"] = headline(row, args.tolerance)
    return row


def candidate(x: torch.Tensor, converged: bool, batch, contact) -> dict:
    """An oracle run's result as a candidate reference: its E_total and whether it converged."""
    return {"energy_total": float(total_energy(x.to(batch.x_init.dtype), batch, contact)[0]),
            "converged": bool(converged)}


def reach(row: dict, index: int) -> dict:
    """The model's point `index` (its T, wall time, energy, E / reference) and each classical
    method's time to that energy (a bound where it did not get there) over the model's time."""
    m = row["methods"]["model"]
    t_model, energy, over_ref = m["points"][index]
    out = {"model_steps": m["steps"][index], "model_s": t_model, "model_energy": energy, "model_over_ref": over_ref}
    for key in ("oracle", "vbd"):
        if key not in row["methods"]:
            continue
        method = row["methods"][key]
        t = first_reach(method["points"], energy)
        reached = math.isfinite(t)
        # not reached: at least its wall time (budget), or never (it converged / settled above)
        t = t if reached else (math.inf if method["converged"] else method["points"][-1][0])
        out[f"{key}_s"], out[f"{key}_bound"], out[f"{key}_ratio"] = t, not reached, t / t_model
    return out


def headline(row: dict, tolerance: float) -> dict:
    """`reach` at the model's first T within `tolerance` of the reference ("tolerance"; None when
    no T gets there) and at its largest T ("final"); the solver alone's first T within
    `tolerance` and its time (None / inf: none); each classical method's time to the tolerance."""
    first = {}
    for key in ("model", "solver"):
        points = row["methods"][key]["points"]
        first[key] = next((i for i, p in enumerate(points) if p[2] <= 1 + tolerance), None)
    solver = row["methods"]["solver"]
    out = {"tolerance": reach(row, first["model"]) if first["model"] is not None else None,
           "final": reach(row, len(row["methods"]["model"]["points"]) - 1),
           "solver_steps": solver["steps"][first["solver"]] if first["solver"] is not None else None,
           "solver_s": solver["points"][first["solver"]][0] if first["solver"] is not None else math.inf}
    target = row["reference"]["energy_total"] * (1 + tolerance)
    for key in ("oracle", "vbd"):
        if key in row["methods"]:
            method = row["methods"][key]
            t = first_reach(method["points"], target)
            out[f"{key}_to_tolerance_s"] = (t if math.isfinite(t) else
                                            math.inf if method["converged"] else method["points"][-1][0])
            out[f"{key}_to_tolerance_bound"] = not math.isfinite(t)
    return out


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def run_header(args) -> dict:
    """Where and how the numbers were made: command, commit, load, threads, date."""
    prov = provenance()
    return {"command": " ".join(shlex.quote(a) for a in [".venv/bin/python", *sys.argv]),
            "git_commit": prov["git_commit"], "git_dirty": prov["git_dirty"],
            "date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "load_average_start": list(os.getloadavg()), "torch_threads": torch.get_num_threads(),
            "cpu_count": os.cpu_count(), "versions": prov}


def _median(values: list[float], bounds: list[bool]) -> dict:
    value, bound = median_bound(values, bounds) if values else (math.nan, False)
    return {"value": value, "bound": bound}


def summarize(rows: list[dict]) -> dict:
    """Medians over instances of the headline numbers, each {"value", "bound"} (bound: a lower
    bound, inf: never). "tolerance": over the instances where the model gets within the
    tolerance (the model's own time over all instances, those that do not counting as above);
    "final": at the model's largest T, over all instances."""
    hl = [r["headline"] for r in rows]
    reached = [h["tolerance"] for h in hl if h["tolerance"] is not None]
    model_s = [h["tolerance"]["model_s"] if h["tolerance"] else math.inf for h in hl]
    solver_s = [h["solver_s"] for h in hl]
    out = {"instances": len(rows), "model_reached": len(reached),
           "tolerance": {"model_s": _median(model_s, [math.isinf(v) for v in model_s]),
                         "model_s_reached": _median([h["model_s"] for h in reached], [False] * len(reached)),
                         "model_steps": _median([h["model_steps"] for h in reached], [False] * len(reached)),
                         "solver_s": _median(solver_s, [math.isinf(v) for v in solver_s])},
           "final": {"model_s": _median([h["final"]["model_s"] for h in hl], [False] * len(hl)),
                     "model_over_ref": _median([h["final"]["model_over_ref"] for h in hl], [False] * len(hl))}}
    for block, records in (("tolerance", reached), ("final", [h["final"] for h in hl])):
        for key in ("oracle", "vbd"):
            if records and all(f"{key}_s" in h for h in records):
                bounds = [h[f"{key}_bound"] for h in records]
                out[block][f"{key}_s"] = _median([h[f"{key}_s"] for h in records], bounds)
                out[block][f"{key}_ratio"] = _median([h[f"{key}_ratio"] for h in records], bounds)
    return out


def _fmt(cell: dict | None, unit: str = "", never: str = "never") -> str:
    """A {"value", "bound"} median (or None: not run) as text: "≥x" a lower bound, `never` inf."""
    if cell is None:
        return "not run"
    if math.isnan(cell["value"]):
        return "–"
    if math.isinf(cell["value"]):
        return never
    return fmt_bound(cell["value"], cell["bound"]) + unit


def write_markdown(path: Path, header: dict, rows: list[dict], summary: dict, args, vbd_note: str) -> None:
    tol = f"{100 * args.tolerance:g} %"
    t_max = args.steps[-1]
    lines = ["# Time to quality: E_total / reference against wall time", "",
             f"Command: `{header['command']}`  ",
             (f"Commit {header['git_commit']}{' (dirty tree)' if header['git_dirty'] else ''}; {header['date_utc']}; "
             f"torch threads {header['torch_threads']} of {header['cpu_count']} CPUs; load average "
             f"{' / '.join(f'{v:.2f}' for v in header['load_average_start'])} (1/5/15 min) at the start, "
             f"{' / '.join(f'{v:.2f}' for v in header['load_average_end'])} at the end.  "),
             (f"{len(rows)} test instance(s) (seed {args.seed}); model T ∈ {{{', '.join(map(str, args.steps))}}}, "
             f"median of {args.repeats} timed call(s) after a warm-up, X_init included; oracle budget "
             f"{args.oracle_budget:g} s, max {args.oracle_max_iters} iterations"
             f"{'' if args.refine else ', no refinement (--no-refine)'}; VBD: {vbd_note}."), ""]
    n, k = summary["instances"], summary["model_reached"]

    def classical(block: dict, key: str) -> str:
        if f"{key}_ratio" not in block:
            return "not run"
        return f"**{_fmt(block[key + '_ratio'], 'x')}** ({_fmt(block[key + '_s'], ' s')})"

    tsum, fsum = summary["tolerance"], summary["final"]
    not_by = f"not by T = {t_max}"
    lines += ["## Headline", "",
              f"- **Model to within {tol} of the reference: {_fmt(tsum['model_s'], ' s', not_by)}** wall per "
              f"garment (median over the {n} instance(s) of the time at the smallest T that gets there; it does "
              f"on {k}/{n}" + (f", at median T = {_fmt(tsum['model_steps'])}, median time over those "
                                f"{_fmt(tsum['model_s_reached'], ' s')}" if k else "") + "). "
              f"Solver alone to {tol}: {_fmt(tsum['solver_s'], ' s', not_by)}."]
    if k:
        lines += [(f"- Time to the energy the model reached there, over the model's time (median over those {k}): "
                  f"oracle {classical(tsum, 'oracle')}, VBD {classical(tsum, 'vbd')}.")]
    lines += [(f"- At T = {t_max} (all {n}): model {_fmt(fsum['model_s'], ' s')}, E / reference "
              f"{fsum['model_over_ref']['value']:.4f}; to that energy: oracle {classical(fsum, 'oracle')}, "
              f"VBD {classical(fsum, 'vbd')}."),
              "", ("≥: a lower bound (the method stopped on its budget first); never: it converged or "
              "settled above that energy. A median is a bound when a bound lies at or below it."), ""]

    def reach_cells(h: dict | None) -> str:
        if h is None:
            return f"{not_by} |" + " |" * 6

        def t(key):
            if f"{key}_s" not in h:
                return "– | –"
            return f"{fmt_bound(h[key + '_s'], h[key + '_bound'])} | {fmt_bound(h[key + '_ratio'], h[key + '_bound'])}"

        return (f"{h['model_steps']} | {h['model_s']:.3g} | {h['model_energy']:.4g} ({h['model_over_ref']:.4f}) "
                f"| {t('oracle')} | {t('vbd')} |")

    head = ("| model T | model [s] | model E [J] (/ ref) | oracle to it [s] | ratio | VBD to it [s] | ratio |")
    lines += [f"## Per instance: the model's first T within {tol}", "",
              "| instance | verts | reference E [J] (from) " + head + f" solver alone T / [s] "
              f"| oracle to {tol} [s] | VBD to {tol} [s] |", "|---" * 13 + "|"]
    for r in rows:
        h, ref = r["headline"], r["reference"]
        solver = (f"{h['solver_steps']} / {h['solver_s']:.3g}" if h["solver_steps"] is not None else not_by)
        tol_cells = " | ".join(fmt_bound(h[f"{key}_to_tolerance_s"], h[f"{key}_to_tolerance_bound"])
                               if f"{key}_to_tolerance_s" in h else "–" for key in ("oracle", "vbd"))
        lines.append(f"| {r['garment']} / body {r['body']} | {r['num_verts']} | {ref['energy_total']:.4g} "
                     f"({ref['source']}) | {reach_cells(h['tolerance'])} {solver} | {tol_cells} |")
    lines += ["", f"## Per instance: the model at T = {t_max}", "", "| instance " + head, "|---" * 8 + "|"]
    for r in rows:
        lines.append(f"| {r['garment']} / body {r['body']} | {reach_cells(r['headline']['final'])}")

    lines += ["", "## Model and solver alone per T (medians over instances)", "",
              "| T | model wall [s] | model E / reference | solver alone wall [s] | solver alone E / reference |",
              "|---|---|---|---|---|"]
    def med(key: str, i: int, j: int) -> float:
        return statistics.median(r["methods"][key]["points"][i][j] for r in rows)

    for i, steps in enumerate(args.steps):
        lines.append(f"| {steps} | {med('model', i, 0):.3g} | {med('model', i, 2):.4f} | {med('solver', i, 0):.3g} "
                     f"| {med('solver', i, 2):.4f} |")

    lines += ["", "## Classical solvers: where they ended", "",
              ("| instance | skinned start E / ref | oracle end | oracle wall [s] | oracle E / ref at its end "
              f"| VBD end | VBD wall [s] (+ setup) | VBD E / ref at its end | oracle refining T={t_max}: end, wall [s] |"),
              "|---" * 9 + "|"]
    for r in rows:
        o = r["methods"]["oracle"]
        v = r["methods"].get("vbd")
        vbd_cells = (f"{v['reason']} | {v['points'][-1][0]:.3g} (+ {v['setup_s']:.2g}) | {v['points'][-1][2]:.4f}"
                     if v else "not run | – | –")
        refined = r.get("refined")
        lines.append(f"| {r['garment']} / body {r['body']} | {r['methods']['oracle']['points'][0][2]:.3f} "
                     f"| {o['reason']} | {o['points'][-1][0]:.3g} | {o['points'][-1][2]:.4f} | {vbd_cells} "
                     f"| {refined['reason'] + ', ' + format(refined['wall_s'], '.3g') if refined else 'not run'} |")
    lines += ["", ("Reference: per instance the lowest E_total of the oracle results at hand (`oracle`: this run's "
              "from the skinned start; `oracle_cached`: the evaluation's cached one from the same start; "
              f"`oracle_refined`: the oracle from the model's T = {t_max} drape; `oracle_settled`: from its T = "
              f"{args.settle_steps} drape). Model times include X_init; the "
              "oracle's are seconds since the start of `relax`; VBD's exclude its setup (model build, colouring, "
              "kernel load, one warm-up step) and its energy checks, as in `bench/bench_vbd.py`."),
              "", f"![E / reference − 1 against wall time]({path.stem}.png)", ""]
    path.write_text("\n".join(lines))


def plot(path: Path, header: dict, rows: list[dict], args) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    floor = 1e-4  # E at or below the reference is drawn here (the axis is logarithmic)
    cols = min(len(rows), 3)
    nrows = math.ceil(len(rows) / cols)
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 4.2 * nrows), squeeze=False)
    styles = {"model": {"color": "C0", "marker": "o", "ms": 3}, "solver": {"color": "C1", "marker": "s", "ms": 3},
              "oracle": {"color": "C2", "marker": ".", "ms": 2}, "vbd": {"color": "C3", "marker": ".", "ms": 2}}
    for ax, r in zip(axes.flat, rows):
        for key, label in METHODS:
            if key not in r["methods"]:
                continue
            pts = [p for p in r["methods"][key]["points"] if p[0] > 0]
            if not pts:
                continue
            ax.plot([p[0] for p in pts], [max(p[2] - 1, floor) for p in pts], label=label, lw=1.2, **styles[key])
        ax.axhline(args.tolerance, color="k", ls="--", lw=0.8, label=f"{100 * args.tolerance:g} % of the reference")
        if r["headline"]["tolerance"] is not None:
            ax.axvline(r["headline"]["tolerance"]["model_s"], color="C0", ls=":", lw=0.8)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{r['garment']} / body {r['body']} ({r['num_verts']} verts)", fontsize=9)
        ax.set_xlabel("wall time [s]")
        ax.set_ylabel("E_total / reference − 1")
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
    for ax in list(axes.flat)[len(rows):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(f"time to quality: {header['torch_threads']} thread(s), commit {str(header['git_commit'])[:8]}, "
                 f"{header['date_utc']}, load {header['load_average_start'][0]:.2f}\n"
                 f"(E at or below the reference drawn at {floor:g}; dotted: the model's first T within "
                 f"{100 * args.tolerance:g} %)", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", default=str(bundled_model()))
    parser.add_argument("--instances", type=int, default=5, help="the first N test instances")
    parser.add_argument("--seed", type=int, default=0, help="the evaluation seed (bodies)")
    parser.add_argument("--steps", type=parse_steps, default=parse_steps("1-15"), help='model T values: "1-15", "1,3,15"')
    parser.add_argument("--repeats", type=int, default=3, help="timed model calls (median) after a warm-up")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--tolerance", type=float, default=0.025, help="the headline's E / reference − 1")
    parser.add_argument("--oracle-budget", type=float, default=120.0, help="oracle wall-time budget per run [s]")
    parser.add_argument("--oracle-max-iters", type=int, default=1000)
    parser.add_argument("--no-refine", dest="refine", action="store_false",
                        help="no oracle from the model's drape at the largest T (the reference is then the oracle's from the skinned start)")
    parser.add_argument("--settle-steps", type=int, default=EvalConfig.oracle_settle_steps,
                        help="also the oracle from the model's drape at this T for the reference (0: not)")
    parser.add_argument("--no-vbd", dest="vbd", action="store_false", help="skip Newton's VBD")
    parser.add_argument("--vbd-budget", type=float, default=120.0, help="VBD wall-time budget per instance [s]")
    parser.add_argument("--vbd-args", default="", help='more bench_vbd.py settings, e.g. "--dt 0.001 --iterations 20"')
    parser.add_argument("--reference-cache", default=str(default_reference_cache()),
                        help='the evaluation\'s cache of oracle results ("" = do not look)')
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: 1 instance, T ∈ {1,2,4,8,15}, 1 repeat, 10 s budgets, no refinement")
    parser.add_argument("--compile", action="store_true", help="the model's network compiled by torch.compile")
    parser.add_argument("--out", default="results", help="folder of time_to_quality.{json,md,png}")
    args = parser.parse_args(argv)
    if args.quick:
        args.instances, args.steps, args.repeats = 1, [1, 2, 4, 8, 15], 1
        args.oracle_budget, args.vbd_budget, args.refine = 10.0, 10.0, False
    torch.set_num_threads(args.threads)
    header = run_header(args)

    if args.vbd:
        vbd, vbd_note = vbd_settings(["--budget", str(args.vbd_budget), *shlex.split(args.vbd_args)])
    else:
        vbd, vbd_note = None, "skipped (--no-vbd)"
    if vbd is not None:
        vbd_note += (f", dt {vbd.dt:.4g} s, {vbd.iterations} iterations, drag {vbd.drag}/s, budget {vbd.budget:g} s "
                     "(bench_vbd.py's settings)")
    log(f"VBD: {vbd_note}")
    # the evaluation's oracle settings (results/eval.md): the cache is looked up under these
    eval_config = EvalConfig(instances=args.instances, seed=args.seed, oracle_budget_s=120.0, oracle_max_iters=1000,
                             threads=args.threads)
    args.oracle_config = dataclasses.replace(eval_config, oracle_budget_s=args.oracle_budget,
                                             oracle_max_iters=args.oracle_max_iters)
    model, info = load_model(args.checkpoint, variant=Variant.FULL)
    if args.compile:
        model.gnn.compile_network()
    contact = Contact.of(model)
    cache = ReferenceCache(args.reference_cache) if args.reference_cache else None
    instances = split_instances(eval_config, get_anny_body())
    rows = []
    for inst in instances:
        log(f"[{inst.index + 1}/{len(instances)}] {inst.garment} ({inst.num_verts} verts), body {inst.body_index}")
        rows.append(instance_run(inst, model, contact, args, eval_config, cache, vbd))
    header["load_average_end"] = list(os.getloadavg())
    summary = summarize(rows)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = {k: v for k, v in vars(args).items() if k != "oracle_config"}
    payload = {"format": "physdrape-time-to-quality-1", **header, "checkpoint": info, "config": config,
               "vbd": vbd_note, "methods": dict(METHODS), "point_fields": ["wall_s", "energy_total_J", "energy_over_reference"],
               "summary": summary, "instances": rows,
               "note": "null times: never reached (the method converged or settled above that energy)"}
    (out / "time_to_quality.json").write_text(json.dumps(finite_or_none(payload), indent=1) + "\n")
    write_markdown(out / "time_to_quality.md", header, rows, summary, args, vbd_note)
    plot(out / "time_to_quality.png", header, rows, args)
    log(f"wrote {out}/time_to_quality.{{json,md,png}}")
    print((out / "time_to_quality.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
