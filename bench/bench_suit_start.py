"""The start of a suit's drape (X_init) and what it costs, side by side with an earlier commit.

Run: .venv/bin/python bench/bench_suit_start.py --base COMMIT [--suits ../shared/data/makehuman_cc0]
     [--repeats 7] [--steps 15] [--out results/bench_suit_start]

A multi-piece garment's X_init is checked for pieces that cross (`DrapePipeline.build`: a start
whose pieces cross is skinned again without the compression bound). Per MakeHuman suit on the
bodies of `bench/garments_stay_on.py` (slim, average on pose ``random:2``, heavy), through the
public API (`Draper.drape(suit.mhclo, shape=..., pose=..., steps=...)`, the bundled model, every
default): the drape's ``init_s`` phase (posing, skinning, layer order, the check) and the whole
call [ms], this commit's and `--base`'s (exported beside it, `bench_drape.export_base`) taking
turns call by call, medians and the median of the per-call ratios; the face pairs of different
pieces that cross at X_init and in the drape (`geometry.intersections.piece_crossings`) for each.
One torch thread. Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import importlib
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch
from bench_drape import export_base
from garments_stay_on import BODIES, body_shapes
from report import page_head, write_report
from timing import side_by_side, turns

from physdrape.garments.pieces import garment_parts
from physdrape.geometry.intersections import piece_crossings


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the commit to time beside this one")
    parser.add_argument("--suits", default="../shared/data/makehuman_cc0")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--steps", type=int, default=15)
    parser.add_argument("--out", default="results/bench_suit_start")
    args = parser.parse_args()
    torch.set_num_threads(1)
    paths = sorted(Path(args.suits).glob("*/*.mhclo"))
    if not paths:
        raise SystemExit(f"no .mhclo suits under {args.suits}")
    base_dir = Path(tempfile.mkdtemp(prefix="physdrape_base_"))
    export_base(args.base, base_dir)
    sys.path.insert(0, str(base_dir))
    drapers = {k: importlib.import_module(f"{p}.api").Draper() for k, p in
               (("this", "physdrape"), ("base", "physdrape_base"))}
    shapes = body_shapes()
    rows = []
    for path in paths:
        template = drapers["this"].garment(str(path))
        piece = garment_parts(template.verts, template.faces).piece
        for (body, _, pose), shape in zip(BODIES, shapes):
            def drape(which: str):
                t = time.perf_counter()
                [res] = drapers[which].drape(str(path), shape=shape, pose=pose, steps=args.steps)
                return res, 1e3 * (time.perf_counter() - t)

            first = {k: drape(k)[0] for k in drapers}  # first use: transfer fit, posed body, kernels
            samples = {k: {"init": [], "drape": []} for k in drapers}
            for r in range(args.repeats):
                for k in turns(r):
                    res, ms = drape(k)
                    samples[k]["init"].append(1e3 * res.timings["init_s"])
                    samples[k]["drape"].append(ms)
            row = {"suit": path.stem, "body": body, "pose": pose, "verts": len(template.verts),
                   "crossings_x_init": {k: piece_crossings(r.x_init, template.faces, piece) for k, r in first.items()},
                   "crossings_drape": {k: piece_crossings(r.verts, template.faces, piece) for k, r in first.items()},
                   "ms": {}}
            for phase in ("init", "drape"):
                row["ms"][phase] = side_by_side(samples["this"][phase], samples["base"][phase])
            rows.append(row)
            print(f"[suit_start] {path.stem} {body}: init {row['ms']['init']['this']:.1f} against "
                  f"{row['ms']['init']['base']:.1f} ms, crossings at X_init {row['crossings_x_init']}", flush=True)
    load = os.getloadavg()
    command, prov, head = page_head("The start of a suit's drape: pieces crossing at X_init, and its cost")
    lines = [*head, "",
             f"Each MakeHuman suit under `{args.suits}` on the bodies of `bench/garments_stay_on.py` through "
             f"`Draper.drape(suit.mhclo, shape=..., pose=..., steps={args.steps})`, this commit and the base "
             f"{args.base} taking turns call by call; medians over {args.repeats} calls; one torch thread; load "
             f"average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}. init: the drape's `init_s` phase (posing, "
             "skinning, layer order, pieces' check); crossings: face pairs of different pieces that intersect.", "",
             "| suit | body (pose) | crossings at X_init this / base | in the drape this / base | init this [ms] "
             "| base [ms] | this / base | drape this [ms] | base [ms] | this / base |",
             "|---|---|---|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        i, d = r["ms"]["init"], r["ms"]["drape"]
        at_init, in_drape = r["crossings_x_init"], r["crossings_drape"]
        lines.append(f"| {r['suit']} | {r['body']} ({r['pose']}) | {at_init['this']} / {at_init['base']} | "
                     f"{in_drape['this']} / {in_drape['base']} | "
                     f"{i['this']:.1f} | {i['base']:.1f} | {i['ratio']:.2f} | {d['this']:.0f} | {d['base']:.0f} | "
                     f"{d['ratio']:.2f} |")
    ratios = [r["ms"]["init"]["ratio"] for r in rows]
    lines += ["", f"init this / base over the {len(rows)} drapes: median {statistics.median(ratios):.2f}, "
              f"range {min(ratios):.2f}-{max(ratios):.2f}."]
    write_report(args.out, lines, {"command": command, "provenance": prov, "base": args.base, "suits": args.suits,
                                   "repeats": args.repeats, "steps": args.steps, "load_average": load, "rows": rows})


if __name__ == "__main__":
    main()
