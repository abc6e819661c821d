"""Physics core benchmark: the Warp element kernels against their torch twins, for garments of
1k, 4k and 16k vertices.

    .venv/bin/python bench/bench_physics.py [--repeats 30] [--dtype float32] [--threads 1] [--out results/bench_physics]

The energies (strain per face + bending per hinge, what the solver's line search evaluates) and
the forces (strain + bending) of `physdrape.physics` run as Warp kernels
(`physics.element_kernels`); their torch twins (`tests/physics/element_reference.py`, the same
formulas as batched torch ops) are what those functions were before. Forward: the values under
no_grad (the drape). Forces fwd+bwd: the forces and the gradient of a weighted sum of them w.r.t.
x (the Hessian–vector product training needs). The variants alternate in rounds, so machine noise
hits all alike; the table gives medians in ms and the ratios torch / kernel, and is written with
the command and commit to <out>.md / .json.
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import sys
from pathlib import Path

import torch
from report import source_lines, write_report
from timing import median_ms

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "physics"))
import element_reference as twin

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import open_cylinder
from physdrape.physics import (
    Cloth,
    bend_energy,
    bend_forces,
    strain_energy,
    strain_forces,
)
from physdrape.provenance import provenance


def tube_garment(num_verts: int) -> Garment:
    segments = int(round((num_verts * 2.5) ** 0.5))
    rings = max(2, round(num_verts / segments))
    return Garment.from_mesh(*open_cylinder(rings, segments, radius=0.16, length=0.6), name=f"tube{num_verts}")


def _energy(strain, bend, case):
    x0, cloth, _ = case

    def run():
        with torch.no_grad():
            return strain(x0, cloth).sum() + bend(x0, cloth).sum()
    return run


def _forces(strain, bend, case):
    x0, cloth, _ = case

    def run():
        with torch.no_grad():
            return strain(x0, cloth) + bend(x0, cloth)
    return run


def _backward(strain, bend, case):
    x0, cloth, weights = case

    def run():
        x = x0.detach().requires_grad_()
        ((strain(x, cloth) + bend(x, cloth)) * weights).sum().backward()
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 4000, 16000])
    parser.add_argument("--out", default="results/bench_physics")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    dtype = getattr(torch, args.dtype)
    command = "python bench/bench_physics.py " + shlex.join(sys.argv[1:])
    load = os.getloadavg()
    rows = []
    for size in args.sizes:
        garment = tube_garment(size).to(dtype)
        cloth = Cloth.build(garment)
        gen = torch.Generator().manual_seed(0)
        x0 = garment.rest * 1.05 + 0.003 * torch.randn(garment.rest.shape, generator=gen, dtype=dtype)
        weights = torch.randn(x0.shape, generator=gen, dtype=dtype)

        case = (x0, cloth, weights)
        variants = {
            "energy_kernel": _energy(strain_energy, bend_energy, case),
            "energy_torch": _energy(twin.strain_energy, twin.bend_energy, case),
            "forces_kernel": _forces(strain_forces, bend_forces, case),
            "forces_torch": _forces(twin.strain_forces, twin.bend_forces, case),
            "backward_kernel": _backward(strain_forces, bend_forces, case),
            "backward_torch": _backward(twin.strain_forces, twin.bend_forces, case),
        }
        samples = {name: [] for name in variants}
        for _ in range(3):
            for name, fn in variants.items():
                samples[name].append(median_ms(fn, max(1, args.repeats // 3)))
        med = {name: statistics.median(v) for name, v in samples.items()}
        rows.append({"verts": garment.num_verts, "faces": garment.num_faces, "hinges": int(cloth.hinges.shape[0]),
                     **{f"{k}_ms": v for k, v in med.items()}})
    lines = ["# Element energies and forces: Warp kernels against their torch twins", "",
             *source_lines(command, prov := provenance()),
             f"{torch.get_num_threads()} torch thread(s), {args.dtype}; medians of 3 alternating rounds × "
             f"{max(1, args.repeats // 3)} calls; load average (1/5/15 min) {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} "
             "at the start", "",
             "| vertices | faces | energy kernel | energy torch | ratio | forces kernel | forces torch | ratio "
             "| forces fwd+bwd kernel | fwd+bwd torch | ratio |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        cells = []
        for what in ("energy", "forces", "backward"):
            k, t = r[f"{what}_kernel_ms"], r[f"{what}_torch_ms"]
            cells += [f"{k:.2f} ms", f"{t:.2f} ms", f"{t / k:.2f}×"]
        lines.append(f"| {r['verts']} | {r['faces']} | " + " | ".join(cells) + " |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "threads": torch.get_num_threads(),
                                   "dtype": args.dtype, "load_average": load, "rows": rows})


if __name__ == "__main__":
    main()
