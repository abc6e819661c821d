"""Writing drape results: OBJ / PLY (via `geometry.mesh.write_mesh`) and GLB scenes (glTF 2.0, written here:
no mesh library is imported to save a drape), each file atomic."""

from __future__ import annotations

import json
import os
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from physdrape.atomic import write_bytes
from physdrape.geometry.mesh import MeshError, write_mesh

__all__ = ["FORMATS", "glb_bytes", "result_files", "save_result", "to_trimesh", "write_glb", "write_json"]

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


def glb_bytes(meshes: Sequence[tuple[str, np.ndarray, np.ndarray, Sequence[int]]]) -> bytes:
    """One binary glTF 2.0 scene of triangle meshes, each (name, verts (V, 3) [m], faces (F, 3),
    RGBA 0-255) a node of its own with float32 positions, area-weighted vertex normals, uint32
    indices and a double-sided material of that colour (garments are open sheets)."""
    from physdrape.garments.numpy_geometry import vertex_normals  # imports torch: only when a scene is written

    blob, views, accessors, gltf_meshes, materials, nodes = bytearray(), [], [], [], [], []

    def add(array: np.ndarray, target: int, component: int, kind: str, bounds: bool = False) -> int:
        data = array.tobytes()
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data), "target": target})
        blob.extend(data + b"\0" * (-len(data) % 4))
        accessor = {"bufferView": len(views) - 1, "componentType": component, "count": len(array), "type": kind}
        if bounds:
            accessor.update(min=array.min(0).tolist(), max=array.max(0).tolist())
        accessors.append(accessor)
        return len(accessors) - 1

    for k, (name, verts, faces, rgba) in enumerate(meshes):
        verts, faces = np.asarray(verts, np.float64), np.asarray(faces, np.int64)
        if not len(verts) or not len(faces):
            raise MeshError(f"cannot write {name!r} to a glTF scene: it has no vertices or no faces")
        position = add(verts.astype("<f4"), 34962, 5126, "VEC3", bounds=True)
        normal = add(vertex_normals(verts, faces).astype("<f4"), 34962, 5126, "VEC3")
        indices = add(faces.astype("<u4").ravel(), 34963, 5125, "SCALAR")
        materials.append({"name": name, "doubleSided": True, "pbrMetallicRoughness": {
            "baseColorFactor": [c / 255.0 for c in rgba], "metallicFactor": 0.0, "roughnessFactor": 0.9}})
        gltf_meshes.append({"name": name, "primitives": [{"attributes": {"POSITION": position, "NORMAL": normal},
                                                           "indices": indices, "material": k, "mode": 4}]})
        nodes.append({"name": name, "mesh": k})
    gltf = {"asset": {"version": "2.0", "generator": "physdrape"}, "scene": 0,
            "scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes, "meshes": gltf_meshes,
            "materials": materials, "accessors": accessors, "bufferViews": views,
            "buffers": [{"byteLength": len(blob)}]}
    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks


def write_glb(path: str | os.PathLike, result) -> Path:
    """One binary glTF scene holding the body and the garment (y-up metres, glTF's convention)."""
    path = Path(path)
    write_bytes(path, glb_bytes([("body", result.body_verts, result.body_faces, BODY_RGBA),
                                 ("garment", result.verts, result.faces, GARMENT_RGBA)]))
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
