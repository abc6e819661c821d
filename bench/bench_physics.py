"""Physics core benchmark: analytic f_int against −∇E by autograd, for garments of 1k/4k/16k vertices.

Run: .venv/bin/python bench/bench_physics.py [--repeats 30] [--dtype float32] [--threads 1]
Prints a Markdown table of medians (ms) measured side by side in one run, with the ratio
autograd / analytic. Forward = forces only; fwd+bwd = forces and the gradient of a scalar of
them w.r.t. x (what training needs, as the solver's output is differentiated).
"""

from __future__ import annotations

import argparse
import statistics

import torch
from timing import median_ms

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import open_cylinder
from physdrape.physics import Cloth, internal_energy, internal_forces


def tube_garment(num_verts: int) -> Garment:
    segments = int(round((num_verts * 2.5) ** 0.5))
    rings = max(2, round(num_verts / segments))
    return Garment.from_mesh(*open_cylinder(rings, segments, radius=0.16, length=0.6), name=f"tube{num_verts}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 4000, 16000])
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, {args.dtype}, median of {args.repeats}")
    print()
    print("| vertices | faces | f_int analytic | −∇E autograd | ratio | f_int fwd+bwd | −∇E autograd fwd+bwd (double backward) | ratio |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    for size in args.sizes:
        garment = tube_garment(size).to(dtype)
        cloth = Cloth.build(garment)
        gen = torch.Generator().manual_seed(0)
        x0 = garment.rest * 1.05 + 0.003 * torch.randn(garment.rest.shape, generator=gen, dtype=dtype)
        weights = torch.randn(x0.shape, generator=gen, dtype=dtype)

        def analytic():
            with torch.no_grad():
                return internal_forces(x0, cloth)

        def autograd():
            x = x0.detach().requires_grad_()
            (grad,) = torch.autograd.grad(internal_energy(x, cloth).sum(), x)
            return -grad

        def analytic_backward():
            x = x0.detach().requires_grad_()
            (internal_forces(x, cloth) * weights).sum().backward()

        def autograd_backward():
            x = x0.detach().requires_grad_()
            (grad,) = torch.autograd.grad(internal_energy(x, cloth).sum(), x, create_graph=True)
            (-(grad * weights).sum()).backward()

        # Interleave the variants so machine noise hits all of them alike.
        results = {name: [] for name in ("a", "g", "ab", "gb")}
        for _ in range(3):
            for name, fn in (("a", analytic), ("g", autograd), ("ab", analytic_backward), ("gb", autograd_backward)):
                results[name].append(median_ms(fn, max(1, args.repeats // 3)))
        a, g, ab, gb = (statistics.median(results[k]) for k in ("a", "g", "ab", "gb"))
        print(
            f"| {garment.num_verts} | {garment.num_faces} | {a:.2f} ms | {g:.2f} ms | {g / a:.2f}× "
            f"| {ab:.2f} ms | {gb:.2f} ms | {gb / ab:.2f}× |"
        )


if __name__ == "__main__":
    main()
