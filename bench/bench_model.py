"""PhysDrape model benchmark: inference per garment and a training step, CPU default vs paper size.

Run: .venv/bin/python bench/bench_model.py [--repeats 5] [--threads 0] [--sizes 32x4 32x4l4 128x16]
    [--solvers explicit two_level]
(a size is latent x blocks, optionally l + coarse graph levels; a solver is the stretching
solver's kind, `model.stretching_solver.SolverKind`).
Garments: open tubes of ~4k vertices; bodies: icospheres of ~10k vertices (the body query cost
is of the order of a real body's). Prints medians (ms) measured side by side in one run; then the
collision handler alone, with and without its centroid pass.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch
from timing import median_ms
import trimesh

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import open_cylinder
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput, ModelConfig, PhysDrape
from physdrape.physics import Cloth
from physdrape.train.loss import LossConfig, drape_loss


#: Each solver kind's step scale and settings: the explicit solver's as the paper's baseline
#: trains it, the two-level solver's the shipped ones (`ModelConfig()`).
SETTINGS = {
    "explicit": dict(eta=1e-3, gamma=0.9, max_step=5e-3),
    "two_level": dict(eta=1.0, gamma=0.98, max_step=1e-2, requery_every=3),
}


def problem(batch_size: int, num_verts: int) -> DrapeInput:
    segments = int(round((num_verts * 2.5) ** 0.5))
    rings = round(num_verts / segments)
    verts, faces = open_cylinder(rings, segments, radius=0.17, length=0.6)
    verts[:, 1] -= 0.3
    garment = Garment.from_mesh(verts, faces, dtype=torch.float32)
    batch = GarmentBatch.pack([garment] * batch_size)
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=0.16)
    body = torch.tensor(np.asarray(sphere.vertices), dtype=torch.float32)
    bodies = BodySurface(body.expand(batch_size, -1, -1).contiguous(), torch.tensor(np.asarray(sphere.faces)))
    return DrapeInput(batch, Cloth.build(batch), batch.rest.clone(), bodies, batch.vert_garment)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=0)
    parser.add_argument("--verts", type=int, default=4000)
    parser.add_argument("--sizes", nargs="+", default=["32x4", "32x4l4", "64x8", "128x16"],
                        help="latent x blocks [l levels], e.g. 32x4l4")
    parser.add_argument("--solvers", nargs="+", default=["explicit", "two_level"], choices=list(SETTINGS),
                        help="stretching solver kinds")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, float32, median of {args.repeats}")
    single, eight = problem(1, args.verts), problem(8, args.verts)
    print(f"garment: {single.garments.num_verts} vertices; body: {single.bodies.num_verts} vertices\n")
    print("| model (D×L, levels, solver) | params | T=3, batch 1 | T=15, batch 1 | T=3, batch 8 (per garment) | T=15, batch 8 (per garment) | train step, batch 1 | train step, batch 8 |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    runs = [(size, solver) for size in args.sizes for solver in args.solvers]
    for size, solver in runs:
        dims, _, levels = size.partition("l")
        latent, blocks = (int(v) for v in dims.split("x"))
        levels = int(levels or 0)
        torch.manual_seed(0)
        model = PhysDrape(ModelConfig(latent=latent, blocks=blocks, levels=levels, solver=solver, **SETTINGS[solver]))
        model.accumulate_statistics(single)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-5)
        params = sum(p.numel() for p in model.parameters())

        def infer(batch, steps):
            model.eval()
            with torch.no_grad():
                model(batch, steps=steps)

        def train(batch):
            model.train()
            out = model(batch)
            loss, _ = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, LossConfig(),
                                 contact_stiffness=model.config.contact_stiffness, margin=model.config.margin)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()

        cells = [
            median_ms(lambda: infer(single, 3), args.repeats),
            median_ms(lambda: infer(single, 15), args.repeats),
            median_ms(lambda: infer(eight, 3), args.repeats) / 8,
            median_ms(lambda: infer(eight, 15), args.repeats) / 8,
            median_ms(lambda: train(single), args.repeats),
            median_ms(lambda: train(eight), args.repeats),
        ]
        print(f"| {latent}×{blocks}, {levels}, {solver} | {params:,} | " + " | ".join(f"{c:.1f} ms" for c in cells) + " |")

    # the collision handler alone: the paper's vertex push, and with the centroid pass
    handler = PhysDrape(ModelConfig()).handler.eval()
    x, faces = single.x_init, single.garments.faces

    def handle(with_faces: bool):
        with torch.no_grad():
            handler(x, single.bodies, single.body_index, faces=faces if with_faces else None)

    vertex, both = median_ms(lambda: handle(False), args.repeats), median_ms(lambda: handle(True), args.repeats)
    print("\n| collision handler, batch 1 | ms |\n|---|---:|")
    print(f"| vertex push (paper Eq. 11) | {vertex:.1f} |\n| + centroid pass (`centroid_margin`) | {both:.1f} |")


if __name__ == "__main__":
    main()
