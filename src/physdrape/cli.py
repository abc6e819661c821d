"""The `physdrape` command line. It calls only the public API and the library's functions."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from physdrape.config_io import ConfigError
from physdrape.geometry.garment import Garment
from physdrape.geometry.mesh import MeshError, read_mesh
from physdrape.geometry.primitives import open_cylinder
from physdrape.physics import Cloth, Material, internal_forces
from physdrape.physics.forces import energy_terms
from physdrape.train.checkpoint import CheckpointError


def _load_garment(path: str | None) -> Garment:
    if path is None:
        verts, faces = open_cylinder(24, 48, radius=0.16, length=0.6)
        return Garment.from_mesh(verts, faces, name="bundled tube")
    verts, faces = read_mesh(path)
    return Garment.from_mesh(verts, faces, name=str(path))


def cmd_drape(args: argparse.Namespace) -> int:
    garment = _load_garment(args.garment)
    material = Material()
    cloth = Cloth.build(garment, material)
    x = garment.rest
    terms = {name: float(value[0]) for name, value in energy_terms(x, cloth).items()}
    force = internal_forces(x, cloth)
    report = {
        "garment": garment.name,
        "num_verts": garment.num_verts,
        "num_faces": garment.num_faces,
        "boundary_loops": len(garment.boundary_loops),
        "energies_J": terms,
        "max_force_N": float(force.norm(dim=-1).max()),
        "note": "physics of the rest garment only: the neural drape lands with the body and model issues",
    }
    print(json.dumps(report, indent=2))
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """Train a model (data-parallel under torchrun: gloo on CPU, NCCL on GPUs)."""
    import os

    import torch.distributed as dist

    from physdrape.config_io import load_config
    from physdrape.train.data import DrapeSource
    from physdrape.train.trainer import TrainConfig, Trainer

    config = load_config(TrainConfig, args.config)
    if args.steps is not None:
        from dataclasses import replace

        config = replace(config, optim=replace(config.optim, steps=args.steps))
    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if distributed:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        trainer = Trainer(config, DrapeSource(config.data), args.run_dir)
        trainer.run(resume=args.resume)
    finally:
        if distributed:
            dist.barrier()  # no rank tears gloo down while another still talks to it
            dist.destroy_process_group()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="physdrape", description="Drape garments onto bodies with PhysDrape.")
    sub = parser.add_subparsers(dest="command", required=True)
    drape = sub.add_parser("drape", help="drape a garment (default: the bundled one)")
    drape.add_argument("--garment", help="garment template mesh (.obj/.ply, metres, y-up)")
    drape.set_defaults(func=cmd_drape)
    train = sub.add_parser("train", help="train a PhysDrape model (self-supervised, resumable)")
    train.add_argument("--config", required=True, help="YAML run config (see configs/cpu_default.yaml)")
    train.add_argument("--run-dir", required=True, help="directory for checkpoints, metrics.jsonl, TensorBoard")
    train.add_argument("--resume", action="store_true", help="continue from the run directory's latest checkpoint")
    train.add_argument("--steps", type=int, help="override optim.steps")
    train.add_argument("--threads", type=int, default=0, help="torch threads per process (0: torch's default)")
    train.set_defaults(func=cmd_train)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (MeshError, ConfigError, CheckpointError) as exc:
        print(f"physdrape: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
