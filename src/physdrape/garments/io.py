"""Garment template files: OBJ/PLY in, deterministic binary PLY out.

Templates are read with `physdrape.geometry.mesh.read_mesh` (vertex order preserved, never
merged; polygons triangulated) and must be in metres, y-up, in the canonical body's frame.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np

from physdrape.atomic import write_bytes
from physdrape.garments.generator import GarmentTemplate
from physdrape.garments.validate import validate_garment
from physdrape.geometry.mesh import MeshError, ply_bytes, read_mesh

__all__ = ["load_template", "write_ply", "read_ply", "sha256_file", "default_garment"]


def load_template(path: str | os.PathLike, *, validate: bool = True, body=None) -> GarmentTemplate:
    """Load a garment template (.obj or .ply, metres, y-up) and check it.

    Args:
        path: the file.
        validate: run `validate_garment` without the clearance requirement (a template from
            elsewhere may touch the body) and raise `GarmentError` on hard failures.
        body: (verts, faces) for the body check; None = canonical body; False = skip it.

    Raises:
        MeshError (file missing / unreadable / unsupported) or GarmentError (invalid mesh).
    """
    path = Path(path)
    verts, faces = read_mesh(path)
    g = GarmentTemplate(verts=verts, faces=faces, name=path.stem)
    if validate:
        report = validate_garment(verts, faces, name=path.name, body=body,
                                  require_clearance=False, max_inside_area_fraction=0.05)
        report.raise_if_failed()
        g.meta["report"] = report
    return g


def write_ply(path: str | os.PathLike, verts: np.ndarray, faces: np.ndarray) -> str:
    """Write a binary little-endian PLY (float64 vertices, int32 triangles) byte-for-byte
    deterministically (`geometry.mesh.ply_bytes`), atomically; returns its sha256."""
    data = ply_bytes(verts, faces, name=str(path))
    write_bytes(path, data)
    return hashlib.sha256(data).hexdigest()


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a PLY written by `write_ply` (or any PLY, through read_mesh)."""
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path}")
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    head = data[: end].decode("ascii", "replace") if end > 0 else ""
    if "binary_little_endian" in head and "property double x" in head and "uchar int vertex_indices" in head:
        nv = int(head.split("element vertex ")[1].split()[0])
        nf = int(head.split("element face ")[1].split()[0])
        off = end + len(b"end_header\n")
        verts = np.frombuffer(data, "<f8", nv * 3, off).reshape(nv, 3).astype(np.float64)
        rec = np.frombuffer(data, [("n", "u1"), ("i", "<i4", (3,))], nf, off + nv * 24)
        if (rec["n"] != 3).any():
            raise MeshError(f"{path}: non-triangle faces")
        return verts, rec["i"].astype(np.int64)
    return read_mesh(path)


def sha256_file(path: str | os.PathLike) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def default_garment() -> GarmentTemplate:
    """The bundled default template: a T-shirt on the canonical body (the split's first test
    garment, seed 0), about 3k vertices, 1.5 cm edges, y-up metres."""
    from importlib.resources import files

    res = files("physdrape") / "assets" / "garments" / "tshirt_default.ply"
    verts, faces = read_ply(Path(str(res)))
    return GarmentTemplate(verts=verts, faces=faces, name="tshirt_default")
