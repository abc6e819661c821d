"""MakeHuman clothes (`.mhclo` + `.obj`) refitted onto any Anny phenotype.

An `.mhclo` binds every garment vertex to the MakeHuman base mesh hm08 (19,158 vertices; Anny's
``makehuman`` topology): either one body vertex (``v``) or three with barycentric-like weights
and an offset (``v1 v2 v3 w1 w2 w3 d1 d2 d3``). As in MakeHuman's ``proxy.py`` the placed vertex is

    x = w1·h[v1] + w2·h[v2] + w3·h[v3] + S·d,   S = diag(sx, sy, sz),
    s_axis = |h[a][axis] − h[b][axis]| / den     from the header lines ``x_scale a b den`` etc.

The offsets and `den` are in MakeHuman units (decimetres); h is the body in metres, so S·d comes
out in metres. The raw `.obj` (decimetres, sitting centimetres off the body) is used only for
its faces (quads triangulated) and vertex count.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from physdrape.body.anny_body import get_anny_body
from physdrape.garments.generator import GarmentTemplate
from physdrape.garments.mesh_cleanup import repair_moved_mesh
from physdrape.garments.numpy_geometry import BodyDistance
from physdrape.garments.remesh import SHORT_EDGE_RATIO, remesh
from physdrape.garments.untangle import untangle_garment
from physdrape.geometry.mesh import MeshError, read_obj
from physdrape.geometry.topology import undirected_edges, vertex_adjacency

__all__ = ["MhcloBinding", "read_mhclo", "fit_mhclo", "load_mhclo", "resolve_body_penetration"]

HM08_NUM_VERTS = 19158


@dataclass(frozen=True)
class MhcloBinding:
    """The parsed binding of an `.mhclo` file.

    Attributes:
        name: garment name.
        obj_file: path of the garment's `.obj` (resolved next to the `.mhclo`).
        ref_verts: hm08 vertex indices per garment vertex, shape (V, 3) int64.
        weights: their weights, shape (V, 3) float64.
        offsets: offsets in MakeHuman units (dm), shape (V, 3) float64.
        scales: per axis (a, b, den) or None (scale 1), for x, y, z.
    """

    name: str
    obj_file: Path
    ref_verts: np.ndarray
    weights: np.ndarray
    offsets: np.ndarray
    scales: tuple


def read_mhclo(path: str | os.PathLike) -> MhcloBinding:
    """Parse an `.mhclo` file (MakeHuman proxy/clothes binding to hm08).

    Raises:
        MeshError naming the file and line when the file is missing or malformed.
    """
    path = Path(path)
    if not path.is_file():
        raise MeshError(f".mhclo file not found: {path}")
    name, obj_file = path.stem, None
    scales = {"x_scale": None, "y_scale": None, "z_scale": None}
    refs, weights, offsets = [], [], []
    in_verts = False
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line_no, line in enumerate(fh, 1):
            s = line.split("#", 1)[0].strip()
            if not s:
                continue
            parts = s.split()
            key = parts[0]
            if in_verts:
                try:
                    if len(parts) == 1:
                        refs.append([int(parts[0])] * 3)
                        weights.append([1.0, 0.0, 0.0])
                        offsets.append([0.0, 0.0, 0.0])
                        continue
                    if len(parts) >= 9:
                        refs.append([int(p) for p in parts[0:3]])
                        weights.append([float(p) for p in parts[3:6]])
                        offsets.append([float(p) for p in parts[6:9]])
                        continue
                except ValueError:
                    pass
                in_verts = False  # the vertex block ended: fall through to keywords
            if key == "verts":
                in_verts = True
            elif key == "name" and len(parts) > 1:
                name = parts[1]
            elif key == "obj_file" and len(parts) > 1:
                obj_file = path.parent / " ".join(parts[1:])
            elif key in scales:
                if len(parts) != 4:
                    raise MeshError(f"{path}:{line_no}: expected '{key} vert1 vert2 den', got {s!r}")
                scales[key] = (int(parts[1]), int(parts[2]), float(parts[3]))
            elif key == "basemesh" and len(parts) > 1 and parts[1] != "hm08":
                raise MeshError(f"{path}:{line_no}: basemesh {parts[1]!r} is not supported (only hm08)")
    if not refs:
        raise MeshError(f"{path}: no vertex binding found (a 'verts 0' block) - not an .mhclo file?")
    if obj_file is None:
        obj_file = path.with_suffix(".obj")
    ref = np.asarray(refs, np.int64)
    if ref.min() < 0 or ref.max() >= HM08_NUM_VERTS:
        raise MeshError(f"{path}: body vertex indices outside hm08's [0, {HM08_NUM_VERTS})")
    return MhcloBinding(
        name=name, obj_file=obj_file, ref_verts=ref, weights=np.asarray(weights, np.float64),
        offsets=np.asarray(offsets, np.float64),
        scales=(scales["x_scale"], scales["y_scale"], scales["z_scale"]),
    )


def fit_mhclo(binding: MhcloBinding, hm08: np.ndarray) -> np.ndarray:
    """Place the garment vertices on a body given on the hm08 topology.

    Args:
        binding: parsed `.mhclo`.
        hm08: body vertex positions [m], shape (19158, 3), y-up (MakeHuman's axes).

    Returns:
        garment vertex positions [m], shape (V, 3) float64.
    """
    h = np.asarray(hm08, np.float64)
    if h.shape != (HM08_NUM_VERTS, 3):
        raise MeshError(f"hm08 body must have shape ({HM08_NUM_VERTS}, 3), got {h.shape}")
    s = np.ones(3)
    for axis, data in enumerate(binding.scales):
        if data is not None:
            a, b, den = data
            s[axis] = abs(h[a, axis] - h[b, axis]) / den
    r, w = binding.ref_verts, binding.weights
    return (h[r] * w[:, :, None]).sum(1) + binding.offsets * s


def load_mhclo(
    path: str | os.PathLike,
    *,
    phenotype: dict | None = None,
    hm08: np.ndarray | None = None,
    target_edge: float | None = 0.015,
    resolve_margin: float | None = 2e-3,
    untangle: bool = False,
) -> GarmentTemplate:
    """Load a MakeHuman garment and refit it onto an Anny body.

    Args:
        path: the `.mhclo` file (its `.obj` is found through ``obj_file``).
        phenotype: Anny phenotype values (None: the canonical body, all 0.5).
        hm08: the body on the hm08 topology [m] (19158, 3); overrides `phenotype`.
        target_edge: remesh to this edge length [m] (the MakeHuman meshes have 1.4–3 cm
            edges); None keeps the original mesh (then vertices match the .obj one to one).
        resolve_margin: push vertices inside the body or closer than this [m] out to it
            (`resolve_body_penetration`); None leaves the raw refit. Tight suits refit raw
            have part of their area inside the body (MakeHuman hides the skin under them).
        untangle: after that, separate the pieces' layers where they cross (a top refit through
            trousers; `garments.untangle.untangle_garment`), kept when no crossing is left;
            needs `resolve_margin`.
        A remeshed garment is then cleaned once more (`mesh_cleanup.repair_moved_mesh`): edges
        those moves squeezed under `SHORT_EDGE_RATIO` x target_edge collapsed, slivers flipped,
        folded ones included.

    Returns:
        the garment (y-up metres, on that body).
    """
    b = read_mhclo(path)
    if not b.obj_file.is_file():
        raise MeshError(f"{path}: its obj_file {b.obj_file} was not found next to it")
    obj_v, faces = read_obj(b.obj_file)
    if len(obj_v) != len(b.ref_verts):
        raise MeshError(
            f"{path}: binds {len(b.ref_verts)} vertices but {b.obj_file.name} has {len(obj_v)}; "
            "the .mhclo and .obj do not belong together"
        )
    if hm08 is None:
        hm08 = _anny_hm08_verts(phenotype or {})
    verts = fit_mhclo(b, hm08)
    g = GarmentTemplate(verts=verts, faces=faces, name=b.name, meta={"source": str(path)})
    if target_edge is not None:
        g.verts, g.faces = remesh(verts, faces, target_edge=target_edge)
        g.meta["remeshed"] = target_edge
    if resolve_margin is not None:
        anny = get_anny_body()  # its closed skin is a subset of hm08's vertices
        body_verts = np.asarray(hm08, np.float64)[anny.hm08_ids.numpy()]
        g.verts, moved = resolve_body_penetration(
            g.verts, g.faces, body_verts, anny.faces.numpy(), margin=resolve_margin
        )
        g.meta["resolved_verts"] = int(moved)
        if untangle:
            verts, info = untangle_garment(g.verts, g.faces, body_verts, anny.faces.numpy(), margin=resolve_margin)
            if info.faces_after == 0:  # a partial untangle can leave a layer moved aside (an open front)
                g.verts = verts
            g.meta["untangled"] = info.as_dict() | {"kept": info.faces_after == 0}
    if target_edge is not None:  # the remesher's slivers, and those the moves above squeezed or folded
        count = len(g.verts)
        g.verts, g.faces = repair_moved_mesh(g.verts, g.faces, min_edge=SHORT_EDGE_RATIO * target_edge)
        g.meta["repair_collapsed_verts"] = count - len(g.verts)
    return g


def _anny_hm08_verts(phenotype: dict) -> np.ndarray:
    """The Anny body of `phenotype` (names -> [0, 1], missing ones 0.5) on hm08 [m], (19158, 3)."""
    anny = get_anny_body()
    with torch.no_grad():
        shape = anny.shape_from_dict({k: float(v) for k, v in phenotype.items()}, dtype=torch.float64)
        return anny.hm08_verts(shape)[0].numpy()


def resolve_body_penetration(
    verts: np.ndarray,
    faces: np.ndarray,
    body_verts: np.ndarray,
    body_faces: np.ndarray,
    *,
    margin: float = 2e-3,
    rounds: int = 4,
) -> tuple[np.ndarray, int]:
    """Push garment vertices that are inside the body or closer than `margin` out to it.

    Tight MakeHuman clothes sit partly inside the skin (MakeHuman hides the body under them);
    a drape needs them outside. Each round moves the offending vertices to margin + 0.5 mm
    along the body normal at their closest point, then spreads half of that displacement to
    their neighbours so the sheet does not crease.

    Returns:
        (new positions [m] (V, 3), number of vertices that were moved).
    """
    q = BodyDistance(body_verts, body_faces)
    x = np.array(verts, np.float64)
    adj = vertex_adjacency(len(x), undirected_edges(np.asarray(faces, np.int64)))
    deg = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    moved = np.zeros(len(x), bool)
    for _ in range(rounds):
        d, c, n = q(x)
        low = d < margin
        if not low.any():
            break
        moved |= low
        disp = np.where(low[:, None], c + n * (margin + 5e-4) - x, 0.0)
        spread = (adj @ disp) / deg[:, None]
        x = x + np.where(low[:, None], disp, 0.5 * spread)
    d, c, n = q(x)
    low = d < margin
    x[low] = c[low] + n[low] * (margin + 5e-4)
    return x, int((moved | low).sum())
