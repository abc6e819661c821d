"""Benchmark: time to generate the procedural garment split (target: 630 garments ≤ 10 min).

    python bench/bench_garments.py                    # a seeded subset, extrapolated to 630
    python bench/bench_garments.py --count 40
    python bench/bench_garments.py --full --out DIR --workers 2   # the real 600 + 30 split

Each garment is generated and validated (self-intersections, body clearance); a draw that fails
is redrawn, and the redraws are counted in the time. The subset mode extrapolates linearly and
says so.
"""

from __future__ import annotations

import argparse
import time
from collections import Counter


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--count", type=int, default=24, help="garments in the subset (cycling categories)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--full", action="store_true", help="generate the whole split with make_split")
    ap.add_argument("--out", default=None, help="split directory for --full")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args(argv)

    from physdrape.garments.canonical import canonical_body

    t0 = time.perf_counter()
    canonical_body()
    print(f"canonical body ready in {time.perf_counter() - t0:.1f} s")

    if args.full:
        import tempfile

        from physdrape.garments.split import make_split

        out = args.out or tempfile.mkdtemp(prefix="physdrape_split_")
        t0 = time.perf_counter()
        m = make_split(out, seed=args.seed, workers=args.workers)
        dt = time.perf_counter() - t0
        redraws = sum(g["attempt"] for g in m["garments"])
        nv = [g["num_verts"] for g in m["garments"]]
        print(f"full split: {len(nv)} garments in {dt:.1f} s ({dt / 60:.2f} min, {args.workers} "
              f"workers), {redraws} redraws, verts {min(nv)}-{max(nv)} (mean {sum(nv) / len(nv):.0f}) -> {out}")
        return

    from physdrape.garments.body_fields import body_fields
    from physdrape.garments.generator import GarmentCategory, generate_valid_garment

    body_fields(canonical_body())  # per-process setup (body fields, BVHs, kernel compile)
    generate_valid_garment("tshirt", 10**6)  # warm-up (Warp kernels)
    cats = list(GarmentCategory)
    per_cat, attempts = Counter(), Counter()
    nverts = []
    t0 = time.perf_counter()
    for i in range(args.count):
        c = cats[i % len(cats)]
        t1 = time.perf_counter()
        g, a = generate_valid_garment(c, args.seed * 100_003 + i)
        per_cat[c.value] += time.perf_counter() - t1
        attempts[c.value] += a
        nverts.append(g.num_verts)
    dt = time.perf_counter() - t0
    per = dt / args.count
    print(f"{args.count} garments in {dt:.1f} s = {per:.2f} s/garment (1 process), "
          f"verts {min(nverts)}-{max(nverts)}")
    for c in cats:
        n = sum(1 for i in range(args.count) if cats[i % len(cats)] is c)
        print(f"  {c.value:11s} {per_cat[c.value] / max(n, 1):.2f} s/garment, redraws {attempts[c.value]}")
    print(f"EXTRAPOLATED (linear, from {args.count}) to 630 garments: {630 * per / 60:.1f} min on 1 process")


if __name__ == "__main__":
    main()
