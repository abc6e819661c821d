"""Does `physdrape fit` make valid templates of real multi-piece garments? The five CC0 MakeHuman
suits, each from its `.mhclo` and from its raw `.obj` in decimetres.

Run: .venv/bin/python bench/fit_suits.py [--suits ../shared/data/makehuman_cc0] [--jobs 2]
     [--iters 20] [--time-budget 120] [--out results/fit_suits]

Each file goes through `fit_garment` as `physdrape fit FILE` (`.mhclo`) and
`physdrape fit FILE --units dm` (`.obj`) run it, with the command's defaults (20 relaxation
iterations, 120 s). Per fit: whether the result validates as a template (no self-intersections,
>= 2 mm body clearance), its self-intersecting faces, the crossings the untangling found and left
before and after the relaxation, whether the relaxed shape was discarded for the unrelaxed one,
the translation found for an `.obj`, the self-intersecting faces of the input as authored, and
the wall time. Writes <out>.json and <out>.md atomically, each naming the command and the commit.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from physdrape.atomic import write_text
from physdrape.eval.report import finite_or_none
from physdrape.provenance import provenance


def fit_one(path: str, units: str, iters: int, time_budget: float) -> dict:
    """Fit one file in this process (one torch thread) and measure it."""
    import torch

    torch.set_num_threads(1)
    from physdrape.api import fit_garment
    from physdrape.api.placement import unit_scale
    from physdrape.garments.mhclo import read_mhclo
    from physdrape.geometry.intersections import self_intersecting_faces
    from physdrape.geometry.mesh import read_mesh

    t0 = time.perf_counter()
    result = fit_garment(path, units=units, iters=iters, time_budget_s=time_budget)
    wall = time.perf_counter() - t0
    source = Path(path)
    # as authored, in metres (an .mhclo's .obj is in MakeHuman's decimetres)
    raw_v, raw_f = read_mesh(read_mhclo(source).obj_file if source.suffix == ".mhclo" else source)
    raw_v = raw_v * (0.1 if source.suffix == ".mhclo" else unit_scale(units))
    untangle = result.relax.get("untangle", {})
    return {
        "file": source.name, "units": units if source.suffix != ".mhclo" else None, "valid": bool(result.ok),
        "num_verts": len(result.verts),
        "self_intersecting_faces": len(self_intersecting_faces(result.verts, result.faces)),
        "authored_self_intersecting_faces": len(self_intersecting_faces(raw_v, np.asarray(raw_f, np.int64))),
        "untangle_before_relax": untangle.get("before_relax"), "untangle_after_relax": untangle.get("after_relax"),
        "discarded": result.relax.get("discarded"), "iterations": result.relax.get("iterations"),
        "layer_pairs": result.relax.get("layer_pairs"), "translation_m": result.translation,
        "wall_s": wall, "validation": result.validation,
    }


def markdown(record: dict) -> str:
    rows = record["rows"]
    ok = {ext: sum(r["valid"] for r in rows if r["file"].endswith(ext)) for ext in (".mhclo", ".obj")}
    n = {ext: sum(r["file"].endswith(ext) for r in rows) for ext in (".mhclo", ".obj")}

    def crossings(u):
        return "–" if not u else f"{u['self_intersecting_faces_before']} → {u['self_intersecting_faces_after']}"

    lines = [
        "# `physdrape fit` on the MakeHuman suits: valid templates from .mhclo and from .obj",
        "",
        f"Command: `{record['command']}`  ",
        f"Git commit: `{record['provenance']['git_commit']}`",
        "",
        (f"Valid fitted templates: {ok['.mhclo']} / {n['.mhclo']} from `.mhclo`, {ok['.obj']} / {n['.obj']} from "
         "`.obj` with `--units dm`."),
        "",
        ("| file | valid | self-intersecting faces | as authored | untangled before relaxing | after relaxing | "
         "relaxed shape discarded | layer pairs | translation [m] | wall [s] |"),
        "|---|---|---:|---:|---|---|---|---:|---|---:|",
    ]
    for r in rows:
        t = "–" if r["units"] is None else "(" + ", ".join(f"{v:.3f}" for v in r["translation_m"]) + ")"
        lines.append(f"| {r['file']} | {'yes' if r['valid'] else 'no'} | {r['self_intersecting_faces']} | "
                     f"{r['authored_self_intersecting_faces']} | {crossings(r['untangle_before_relax'])} | "
                     f"{crossings(r['untangle_after_relax'])} | {'yes' if r['discarded'] else 'no'} | "
                     f"{r['layer_pairs'] if r['layer_pairs'] is not None else '–'} | {t} | {r['wall_s']:.0f} |")
    lines += ["", ("Untangling columns: self-intersecting faces found → left. The relaxed shape is discarded "
                   "(the unrelaxed, untangled one kept) when the relaxation left crossings the untangling could not "
                   "remove while the unrelaxed shape had none.")]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suits", type=Path, default=Path("../shared/data/makehuman_cc0"))
    parser.add_argument("--jobs", type=int, default=2, help="fits run at once, one process each")
    parser.add_argument("--iters", type=int, default=20)
    parser.add_argument("--time-budget", type=float, default=120.0)
    parser.add_argument("--out", type=Path, default=Path("results/fit_suits"))
    args = parser.parse_args(argv)
    command = "python " + shlex.join(sys.argv if argv is None else ["bench/fit_suits.py", *argv])
    mhclo = sorted(args.suits.glob("*/*.mhclo"))
    if not mhclo:
        raise SystemExit(f"no .mhclo files under {args.suits}/*/: give --suits DIR (the CC0 MakeHuman suits)")
    work = [(str(p), "m") for p in mhclo] + [(str(p.with_suffix(".obj")), "dm") for p in mhclo]
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = [pool.submit(fit_one, path, units, args.iters, args.time_budget) for path, units in work]
        rows = []
        for f in futures:
            rows.append(f.result())
            r = rows[-1]
            print(f"{r['file']}: {'valid' if r['valid'] else 'INVALID'}, {r['self_intersecting_faces']} "
                  f"self-intersecting faces ({r['wall_s']:.0f} s)", flush=True)
    record = {"command": command, "provenance": provenance(), "config": {k: str(v) for k, v in vars(args).items()},
              "rows": rows}
    write_text(args.out.with_suffix(".json"), json.dumps(finite_or_none(record), indent=1, allow_nan=False) + "\n")
    write_text(args.out.with_suffix(".md"), markdown(record))
    print(markdown(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
