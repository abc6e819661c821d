"""The layer pairs' search on the MakeHuman suits, side by side with an earlier commit.

Run: .venv/bin/python bench/bench_layer_pairs.py --base COMMIT [--makehuman ../shared/data/makehuman_cc0]
     [--eval results/eval.json] [--repeats 9] [--out results/bench_layer_pairs]

A multi-piece garment's layer order is completed by pairs found where the pieces are
(`physics.layers.follow_pairs`) in every iteration of the oracle far from rest and in every
drape's measured energy (`physics.energy.drape_energies`). Per suit of `physdrape eval
--makehuman` (the evaluation record `--eval`'s instances, at their X_init, in its dtype), both
timed with this commit's source and with `--base`'s (exported beside it as `physdrape_base`,
`bench_drape.export_base`), the two taking turns call by call; medians [ms] and the median of the
per-call ratios; whether the two found the same pairs (with the same normals, in any order). One
torch thread. Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import sys
import tempfile
from pathlib import Path

import torch
from bench_drape import export_base
from eval_record import suit_instances
from report import page_head, write_report
from timing import call_ms, speedups

from physdrape.model.config import ModelConfig


def _pair_set(pairs: torch.Tensor, normals: torch.Tensor) -> set:
    """The pairs with their normals, as a set (their order carries no meaning)."""
    return set(zip(map(tuple, pairs.tolist()), map(tuple, normals.tolist())))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the commit to time beside this one")
    parser.add_argument("--makehuman", default="../shared/data/makehuman_cc0")
    parser.add_argument("--eval", default="results/eval.json", help="the evaluation record naming the suits")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--out", default="results/bench_layer_pairs")
    args = parser.parse_args()
    torch.set_num_threads(1)
    instances, _, record, _ = suit_instances(args.eval, args.makehuman)
    settings = record["config"]
    model = ModelConfig()  # the contact penalty's k_c and ε, as the evaluation measures
    base_dir = Path(tempfile.mkdtemp(prefix="physdrape_base_"))
    export_base(args.base, base_dir)
    sys.path.insert(0, str(base_dir))
    versions = {"this": "physdrape", "base": "physdrape_base"}
    follow = {k: importlib.import_module(f"{p}.physics.layers").follow_pairs for k, p in versions.items()}
    energies = {k: importlib.import_module(f"{p}.physics.energy").drape_energies for k, p in versions.items()}
    rows = []
    for inst in instances:
        batch, _, _ = inst.batch()
        layers, x = batch.cloth.layers, batch.x_init
        if layers is None or not layers.follows:
            continue
        found = {k: f(x, layers) for k, f in follow.items()}  # also the first calls: kernels loaded
        same = _pair_set(*found["this"]) == _pair_set(*found["base"])
        calls = {
            "follow_pairs": {k: (lambda f=f: f(x, layers)) for k, f in follow.items()},
            "measured energy": {k: (lambda e=e: e(x, batch.cloth, batch.bodies, batch.body_index,
                                                  contact_stiffness=model.contact_stiffness, margin=model.margin))
                                for k, e in energies.items()},
        }
        for call in calls["measured energy"].values():
            call()
        row = {"garment": inst.garment, "verts": int(len(x)), "pieces": torch.bincount(layers.piece).tolist(),
               "pairs": {k: int(len(v[0])) for k, v in found.items()}, "same_pairs": same, "ms": {}}
        for name, pair in calls.items():
            samples = {"this": [], "base": []}
            for r in range(args.repeats):
                for k in (("this", "base") if r % 2 == 0 else ("base", "this")):
                    samples[k].append(call_ms(pair[k]))
            row["ms"][name] = {k: statistics.median(v) for k, v in samples.items()}
            row["ms"][name]["ratio"] = statistics.median(speedups(samples["this"], samples["base"]))
        rows.append(row)
        print(f"[layer_pairs] {inst.garment}: " + ", ".join(
            f"{n} {v['this']:.1f} against {v['base']:.1f} ms" for n, v in row["ms"].items()), flush=True)
    load = os.getloadavg()
    command, prov, head = page_head("The layer pairs' search on the MakeHuman suits")
    lines = [*head, "",
             f"The suits of `{args.eval}`'s MakeHuman set with a followed layer order, at their X_init "
             f"({settings['dtype']}); medians over {args.repeats} calls, this commit and the base {args.base} taking "
             f"turns; one torch thread; load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}. "
             "measured energy: `physics.energy.drape_energies` (the pairs' search, every term, the body contact "
             "of vertices and centroids).", "",
             "| suit | vertices (pieces) | pairs this / base (same) | follow_pairs this [ms] | base [ms] | base / this "
             "| measured energy this [ms] | base [ms] | base / this |",
             "|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        f, e = r["ms"]["follow_pairs"], r["ms"]["measured energy"]
        lines.append(f"| {r['garment']} | {r['verts']} ({', '.join(map(str, r['pieces']))}) | "
                     f"{r['pairs']['this']} / {r['pairs']['base']} ({'yes' if r['same_pairs'] else 'no'}) | "
                     f"{f['this']:.1f} | {f['base']:.1f} | {f['ratio']:.1f} | "
                     f"{e['this']:.1f} | {e['base']:.1f} | {e['ratio']:.2f} |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "base": args.base, "eval": args.eval,
                                   "repeats": args.repeats, "load_average": load, "suits": rows})


if __name__ == "__main__":
    main()
