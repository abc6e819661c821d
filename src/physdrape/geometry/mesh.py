"""Triangle-mesh files and input checks.

Garment topology is fixed by its file: vertices keep the file's order and are never merged (a
merge would silently change the rest state). Polygons are fan-triangulated. Every public check
raises `MeshError` naming the faces or vertices at fault and what to do about them.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from physdrape.atomic import write_bytes

#: A garment wider than this [m] is almost certainly not in metres (a 170-unit body is in cm).
MAX_GARMENT_EXTENT_M = 3.0
#: A rest triangle with a smaller area [m²] is degenerate (1 mm² ≈ an edge of 1.4 mm).
MIN_FACE_AREA_M2 = 1e-9


class MeshError(ValueError):
    """A mesh that PhysDrape cannot use as it is; the message says what is wrong and the fix."""


def _show(indices: np.ndarray, limit: int = 10) -> str:
    indices = np.asarray(indices).ravel()
    head = ", ".join(str(int(i)) for i in indices[:limit])
    return head + (f", … ({indices.size} in all)" if indices.size > limit else "")


def read_obj(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a Wavefront OBJ keeping the file's vertex order; polygons are fan-triangulated.

    Returns:
        verts: vertex positions as written in the file, shape (V, 3) float64.
        faces: triangle vertex indices, shape (F, 3) int64.
    """
    verts: list[list[float]] = []
    faces: list[list[int]] = []
    with open(path, encoding="utf-8", errors="replace") as handle:
        for line_no, line in enumerate(handle, start=1):
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                if len(parts) < 4:
                    raise MeshError(f"{path}:{line_no}: a vertex needs 3 coordinates: {line.strip()!r}")
                verts.append([float(c) for c in parts[1:4]])
            elif parts[0] == "f":
                if len(parts) < 4:
                    raise MeshError(f"{path}:{line_no}: a face needs at least 3 vertices: {line.strip()!r}")
                corners = []
                for token in parts[1:]:
                    index = int(token.split("/")[0])
                    # OBJ indices are 1-based; negative ones count back from the last vertex read.
                    corners.append(index - 1 if index > 0 else len(verts) + index)
                for k in range(1, len(corners) - 1):
                    faces.append([corners[0], corners[k], corners[k + 1]])
    return np.asarray(verts, dtype=np.float64).reshape(-1, 3), np.asarray(faces, dtype=np.int64).reshape(-1, 3)


def read_mesh(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a triangle mesh (OBJ or PLY), vertex order preserved, no vertex merging.

    Returns:
        verts: vertex positions, shape (V, 3) float64 (in the file's unit; see `check_mesh`).
        faces: triangle vertex indices, shape (F, 3) int64 (quads and polygons triangulated).
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f"mesh file not found: {path} (give the path of an .obj or .ply file)")
    suffix = path.suffix.lower()
    if suffix == ".obj":
        verts, faces = read_obj(path)
    elif suffix == ".ply":
        import trimesh

        try:
            mesh = trimesh.load(path, process=False, force="mesh")
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise MeshError(f"could not read {path} as PLY: {exc}") from exc
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces, dtype=np.int64)
    else:
        raise MeshError(f"unsupported mesh format {suffix!r} for {path}: use .obj or .ply")
    if len(faces) == 0:
        raise MeshError(f"{path} has no faces: a garment must be a triangle (or polygon) mesh")
    return verts, faces


def ply_bytes(verts: np.ndarray, faces: np.ndarray, *, name: str = "mesh") -> bytes:
    """A binary little-endian PLY of a triangle mesh (float64 vertices, int32 corner indices),
    the same bytes for the same arrays (a fixed header, no timestamps)."""
    verts = np.ascontiguousarray(verts, dtype="<f8")
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(verts)):
        raise MeshError(f"{name}: face indices out of range [0, {len(verts)})")
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {len(verts)}\nproperty double x\nproperty double y\nproperty double z\n"
        f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    rec["n"] = 3
    rec["i"] = faces
    return header + verts.tobytes() + rec.tobytes()


def write_mesh(path: str | os.PathLike, verts: np.ndarray, faces: np.ndarray) -> None:
    """Write an OBJ or a binary PLY (`ply_bytes`) atomically (a temporary file renamed into place)."""
    path = Path(path)
    suffix = path.suffix.lower()
    verts = np.asarray(verts, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if suffix == ".obj":
        lines = [f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in verts]
        lines += [f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces]
        write_bytes(path, "".join(lines).encode())
    elif suffix == ".ply":
        write_bytes(path, ply_bytes(verts, faces, name=str(path)))
    else:
        raise MeshError(f"unsupported mesh format {suffix!r} for {path}: use .obj or .ply")


def face_areas(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Triangle areas, shape (F,) in the square of the vertices' unit."""
    v0, v1, v2 = (verts[faces[:, k]] for k in range(3))
    return 0.5 * np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=1)


def check_mesh(verts: np.ndarray, faces: np.ndarray, *, name: str = "mesh") -> None:
    """Raise `MeshError` unless (verts, faces) is a usable garment rest state in metres.

    Checked, in order: shapes, finite coordinates, face indices in range, repeated corners,
    the unit (largest extent ≤ 3 m), zero-area triangles, and edges shared by more than two faces.
    Nothing is fixed silently: the error names the vertices or faces at fault.
    """
    verts = np.asarray(verts)
    faces = np.asarray(faces)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise MeshError(f"{name}: vertices must have shape (V, 3), got {tuple(verts.shape)}")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"{name}: faces must have shape (F, 3) (triangles), got {tuple(faces.shape)}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise MeshError(f"{name}: face indices must be integers, got dtype {faces.dtype}")
    bad = np.flatnonzero(~np.isfinite(verts).all(axis=1))
    if bad.size:
        raise MeshError(f"{name}: vertices {_show(bad)} have NaN or infinite coordinates; fix or remove them")
    out = np.flatnonzero(((faces < 0) | (faces >= len(verts))).any(axis=1))
    if out.size:
        raise MeshError(
            f"{name}: faces {_show(out)} index vertices outside [0, {len(verts)}); "
            "the face list does not match the vertex list"
        )
    repeated = np.flatnonzero(
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    )
    if repeated.size:
        raise MeshError(f"{name}: faces {_show(repeated)} repeat a vertex; remove these degenerate faces")
    used = np.unique(faces)
    extent = float((verts[used].max(axis=0) - verts[used].min(axis=0)).max())
    if extent > MAX_GARMENT_EXTENT_M:
        raise MeshError(
            f"{name}: the mesh is {extent:.4g} units across, which is not a garment in metres "
            f"(PhysDrape uses metres); if the file is in centimetres scale it by 0.01, in "
            "decimetres by 0.1, in millimetres by 0.001"
        )
    areas = face_areas(verts.astype(np.float64), faces)
    degenerate = np.flatnonzero(areas < MIN_FACE_AREA_M2)
    if degenerate.size:
        raise MeshError(
            f"{name}: faces {_show(degenerate)} have (near) zero rest area (< {MIN_FACE_AREA_M2:g} m²); "
            "remove or remesh them (physdrape cannot define their rest shape)"
        )
    from physdrape.geometry.topology import non_manifold_edges

    bad_edges = non_manifold_edges(faces)
    if len(bad_edges):
        pairs = ", ".join(f"({a}, {b})" for a, b in bad_edges[:10])
        raise MeshError(
            f"{name}: {len(bad_edges)} edges are shared by more than two faces (non-manifold), e.g. "
            f"{pairs}; split the garment there or remesh it into a manifold surface"
        )
