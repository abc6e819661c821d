"""Writing drape results: OBJ / PLY (via `geometry.mesh.write_mesh`) and GLB scenes, each file atomic."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from physdrape.atomic import write_bytes
from physdrape.geometry.mesh import MeshError, write_mesh

__all__ = ["FORMATS", "result_files", "save_result", "to_trimesh", "write_glb", "write_json"]

#: Mesh formats `save_result` writes.
FORMATS = ("obj", "ply", "glb")
GARMENT_RGBA = (70, 120, 200, 255)
BODY_RGBA = (205, 190, 175, 255)


def write_json(path: str | os.PathLike, data) -> Path:
    """Write JSON atomically (indent 2, sorted keys)."""
    path = Path(path)
    write_bytes(path, (json.dumps(data, indent=2, sort_keys=True) + "\n").encode())
    return path


def to_trimesh(result, *, with_body: bool = False):
    """The garment of a `DrapeResult` as a `trimesh.Trimesh`, or garment + body as a `trimesh.Scene`."""
    import trimesh

    garment = trimesh.Trimesh(np.asarray(result.verts, np.float64), result.faces, process=False)
    garment.visual.face_colors = GARMENT_RGBA
    if not with_body:
        return garment
    body = trimesh.Trimesh(np.asarray(result.body_verts, np.float64), result.body_faces, process=False)
    body.visual.face_colors = BODY_RGBA
    scene = trimesh.Scene()
    scene.add_geometry(body, node_name="body", geom_name="body")
    scene.add_geometry(garment, node_name="garment", geom_name="garment")
    return scene


def write_glb(path: str | os.PathLike, result) -> Path:
    """One binary glTF scene holding the body and the garment (y-up metres, glTF's convention)."""
    path = Path(path)
    write_bytes(path, to_trimesh(result, with_body=True).export(file_type="glb"))
    return path


def result_files(formats: Sequence[str], *, stem: str = "garment", body_stem: str = "body",
                 scene_stem: str = "drape") -> list[str]:
    """The file names `save_result` writes for these formats."""
    names = []
    for fmt in formats:
        if fmt == "glb":
            names.append(f"{scene_stem}.glb")
        else:
            names += [f"{stem}.{fmt}", f"{body_stem}.{fmt}"]
    return names


def save_result(result, directory: str | os.PathLike, formats: Sequence[str] = FORMATS, *, stem: str = "garment",
                body_stem: str = "body", scene_stem: str = "drape", overwrite: bool = False) -> list[Path]:
    """Write a `DrapeResult`: ``{stem}.obj/.ply`` (garment), ``{body_stem}.obj/.ply`` (posed body),
    ``{scene_stem}.glb`` (both in one scene). Every file is written atomically.

    Raises:
        MeshError: an unknown format, or a file exists and `overwrite` is False (nothing written).
    """
    formats = [f.lower().lstrip(".") for f in formats]
    unknown = sorted(set(formats) - set(FORMATS))
    if unknown:
        raise MeshError(f"unknown export formats {unknown}; choose from {', '.join(FORMATS)}")
    directory = Path(directory)
    names = result_files(formats, stem=stem, body_stem=body_stem, scene_stem=scene_stem)
    if not overwrite:
        existing = [n for n in names if (directory / n).exists()]
        if existing:
            raise MeshError(f"{directory} already holds {', '.join(existing)}: pass overwrite=True (CLI: --force)")
    directory.mkdir(parents=True, exist_ok=True)
    written = []
    for fmt in formats:
        if fmt == "glb":
            written.append(write_glb(directory / f"{scene_stem}.glb", result))
            continue
        for name, verts, faces in ((stem, result.verts, result.faces), (body_stem, result.body_verts, result.body_faces)):
            write_mesh(directory / f"{name}.{fmt}", verts, faces)  # atomic
            written.append(directory / f"{name}.{fmt}")
    return written
