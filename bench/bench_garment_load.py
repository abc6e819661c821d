"""What turning a garment file or a generated garment into a template costs, side by side with an earlier commit.

Run: .venv/bin/python bench/bench_garment_load.py --base COMMIT [--suits ../shared/data/makehuman_cc0]
     [--generated tshirt:0 longsleeve:3 tanktop:5 croptop:7] [--repeats 5] [--out results/bench_garment_load]

`api.specs.garment_template` of each MakeHuman suit (`.mhclo`: placed through its body binding,
remeshed, its pieces untangled, the mesh cleaned) and of generated garments (``CATEGORY:SEED``:
generated on the canonical body and validated), what a `Draper` does once per garment before its
first drape, in this commit and in `--base` (exported beside it, `bench_drape.export_base`), the
two taking turns call by call: medians [ms] and the median of the per-call ratios, and whether the
two commits give the same template (vertices and faces, bit for bit). One torch thread. Writes
<out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import tempfile
from functools import partial
from pathlib import Path

import numpy as np
import torch
from bench_drape import export_base
from report import page_head, write_report
from timing import call_ms, side_by_side, turns


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", required=True, help="the commit to time beside this one")
    parser.add_argument("--suits", default="../shared/data/makehuman_cc0")
    parser.add_argument("--generated", nargs="*", default=["tshirt:0", "longsleeve:3", "tanktop:5", "croptop:7"])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", default="results/bench_garment_load")
    args = parser.parse_args()
    torch.set_num_threads(1)
    specs = [str(p) for p in sorted(Path(args.suits).glob("*/*.mhclo"))] + list(args.generated)
    if not specs:
        raise SystemExit(f"no .mhclo suits under {args.suits} and no generated garments")
    base_dir = Path(tempfile.mkdtemp(prefix="physdrape_base_"))
    export_base(args.base, base_dir)
    sys.path.insert(0, str(base_dir))
    load = {k: importlib.import_module(f"{p}.api.specs").garment_template for k, p in
            (("this", "physdrape"), ("base", "physdrape_base"))}
    for k, p in (("this", "physdrape"), ("base", "physdrape_base")):
        importlib.import_module(f"{p}.body.anny_body").get_anny_body()  # the body model, outside the timing
    rows = []
    for spec in specs:
        first = {k: load[k](spec) for k in load}  # the body's makehuman topology and kernels, outside the timing
        same = all(np.array_equal(np.asarray(getattr(first["this"], a)), np.asarray(getattr(first["base"], a)))
                   for a in ("verts", "faces"))
        samples = {k: [] for k in load}
        for r in range(args.repeats):
            for k in turns(r):
                samples[k].append(call_ms(partial(load[k], spec)))
        name = Path(spec).parent.name if spec.endswith(".mhclo") else spec
        row = {"garment": name, "verts": len(first["this"].verts), "same_template": same,
               "ms": side_by_side(samples["this"], samples["base"])}
        rows.append(row)
        print(f"[garment_load] {name}: {row['ms']['this']:.0f} against {row['ms']['base']:.0f} ms, "
              f"same template {same}", flush=True)
    load_average = os.getloadavg()
    command, prov, head = page_head("A garment's template: what loading or generating it costs")
    lines = [*head, "",
             f"`api.specs.garment_template` of each MakeHuman suit under `{args.suits}` and of generated garments, "
             f"this commit and the base {args.base} taking turns call by call; medians over {args.repeats} calls; "
             f"one torch thread; load average at the end {load_average[0]:.2f} {load_average[1]:.2f} "
             f"{load_average[2]:.2f}. same: the two commits' templates equal bit for bit (vertices and faces).", "",
             "| garment | vertices | this [ms] | base [ms] | this / base | same |",
             "|---|---:|---:|---:|---:|---|"]
    for r in rows:
        m = r["ms"]
        lines.append(f"| {r['garment']} | {r['verts']} | {m['this']:.0f} | {m['base']:.0f} | {m['ratio']:.2f} | "
                     f"{'yes' if r['same_template'] else 'no'} |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "base": args.base, "suits": args.suits,
                                   "generated": args.generated, "repeats": args.repeats,
                                   "load_average": load_average, "rows": rows})


if __name__ == "__main__":
    main()
