"""The `physdrape` command line. It calls only the public API and the library's functions."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from physdrape.geometry.garment import Garment
from physdrape.geometry.mesh import MeshError, read_mesh
from physdrape.geometry.primitives import open_cylinder
from physdrape.physics import Cloth, Material, internal_forces
from physdrape.physics.forces import energy_terms


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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="physdrape", description="Drape garments onto bodies with PhysDrape.")
    sub = parser.add_subparsers(dest="command", required=True)
    drape = sub.add_parser("drape", help="drape a garment (default: the bundled one)")
    drape.add_argument("--garment", help="garment template mesh (.obj/.ply, metres, y-up)")
    drape.set_defaults(func=cmd_drape)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    torch.set_default_dtype(torch.float64)
    try:
        return args.func(args)
    except MeshError as exc:
        print(f"physdrape: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
