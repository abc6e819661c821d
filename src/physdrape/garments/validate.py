"""Validation of garment templates: topology, triangle quality, scale, body clearance.

    report = validate_garment(verts, faces)      # never raises on geometry; see report.ok
    print(report)                                # readable summary
    report.raise_if_failed()                     # GarmentError naming the faces/vertices at fault

Hard failures (`report.errors`): malformed arrays, not in metres (> 3 m across), non-manifold
edges or vertices, degenerate triangles, self-intersections, vertices inside the body, and -
when `require_clearance` - vertices closer to the body than the collision margin. Soft findings
(`report.warnings`): sliver triangles, several connected components, no boundary loop.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from physdrape.garments.canonical import canonical_body
from physdrape.garments.numpy_geometry import BodyDistance
from physdrape.geometry.intersections import self_intersecting_faces
from physdrape.geometry.mesh import MAX_GARMENT_EXTENT_M, MeshError, face_areas
from physdrape.geometry.topology import (
    boundary_loops,
    connected_components,
    non_manifold_edges,
    undirected_edges,
)

__all__ = ["GarmentError", "ValidationReport", "validate_garment", "body_penetration"]

#: A triangle whose smallest angle is below this [deg] is a sliver (warning).
SLIVER_ANGLE_DEG = 5.0
#: A triangle with less area [m²] is degenerate (error).
DEGENERATE_AREA_M2 = 1e-10


class GarmentError(MeshError):
    """A garment template that fails validation; the message names the faces/vertices at fault."""


def _show(idx, limit: int = 8) -> str:
    idx = np.asarray(idx).ravel()
    s = ", ".join(str(int(i)) for i in idx[:limit])
    return s + (f", … ({idx.size} in all)" if idx.size > limit else "")


@dataclass
class ValidationReport:
    """What `validate_garment` found. Lengths in metres, areas in m².

    Attributes:
        name: label of the garment.
        num_verts, num_faces: sizes.
        extent: largest side of the bounding box [m].
        num_components: face-connected components.
        num_boundary_loops: open boundary loops (neck, hem, sleeve ends...).
        euler: Euler characteristic V - E + F.
        mean_edge, min_edge, max_edge: edge lengths [m].
        non_manifold_edges: (K, 2) edges used by more than two faces.
        non_manifold_verts: vertices whose faces form more than one fan.
        degenerate_faces: faces with (near) zero area.
        sliver_faces: faces with a smallest angle below SLIVER_ANGLE_DEG.
        self_intersecting_faces: faces crossing a face they share no vertex with (None: not run).
        inside_verts: vertices inside the body (None: no body check).
        close_verts: vertices closer to the body than the margin (outside it).
        min_clearance: smallest signed vertex distance to the body [m].
        inside_area_fraction: area share of faces whose centroid is inside the body.
        errors, warnings: readable findings.
    """

    name: str
    num_verts: int
    num_faces: int
    extent: float = 0.0
    num_components: int = 0
    num_boundary_loops: int = 0
    euler: int = 0
    mean_edge: float = 0.0
    min_edge: float = 0.0
    max_edge: float = 0.0
    non_manifold_edges: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    non_manifold_verts: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    degenerate_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    sliver_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    self_intersecting_faces: np.ndarray | None = None
    inside_verts: np.ndarray | None = None
    close_verts: np.ndarray | None = None
    min_clearance: float | None = None
    inside_area_fraction: float | None = None
    errors: list = field(default_factory=list)
    warnings: list = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.errors

    def raise_if_failed(self) -> None:
        """Raise `GarmentError` listing every hard failure."""
        if self.errors:
            raise GarmentError(f"garment {self.name!r} failed validation:\n  - " + "\n  - ".join(self.errors))

    def __str__(self) -> str:
        lines = [
            f"garment {self.name!r}: {'OK' if self.ok else 'FAILED'}",
            f"  {self.num_verts} vertices, {self.num_faces} faces, {self.extent:.3f} m across",
            f"  components {self.num_components}, boundary loops {self.num_boundary_loops}, "
            f"Euler characteristic {self.euler}",
            f"  edges: mean {self.mean_edge * 100:.2f} cm, min {self.min_edge * 100:.2f} cm, "
            f"max {self.max_edge * 100:.2f} cm",
            f"  non-manifold edges {len(self.non_manifold_edges)}, vertices "
            f"{len(self.non_manifold_verts)}; degenerate faces {len(self.degenerate_faces)}, "
            f"slivers {len(self.sliver_faces)}",
        ]
        if self.self_intersecting_faces is not None:
            lines.append(f"  self-intersecting faces {len(self.self_intersecting_faces)}")
        if self.inside_verts is not None:
            lines.append(
                f"  body: {len(self.inside_verts)} vertices inside, {len(self.close_verts)} closer "
                f"than the margin, min clearance {self.min_clearance * 1000:.2f} mm, "
                f"{100 * self.inside_area_fraction:.3f} % of the area inside"
            )
        lines += [f"  error: {e}" for e in self.errors]
        lines += [f"  warning: {w}" for w in self.warnings]
        return "\n".join(lines)


def _non_manifold_verts(num_verts: int, faces: np.ndarray) -> np.ndarray:
    """Vertices whose incident faces split into more than one edge-connected fan."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components as cc

    # Corner graph: two corners of the same vertex are linked when their faces share an edge
    # through that vertex. Fans per vertex = components of that graph restricted to the vertex.
    F = len(faces)
    corner_v = faces.ravel()
    he = []  # (vertex, other endpoint, corner id)
    for k in range(3):
        for j in (1, 2):
            he.append(np.stack([faces[:, k], faces[:, (k + j) % 3], np.arange(F) * 3 + k], 1))
    he = np.concatenate(he)
    key = he[:, 0] * num_verts + he[:, 1]
    order = np.argsort(key, kind="stable")
    key, he = key[order], he[order]
    same = key[1:] == key[:-1]
    a, b = he[:-1, 2][same], he[1:, 2][same]
    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(3 * F, 3 * F))
    _, lab = cc(g, directed=False)
    fans = np.unique(np.stack([corner_v, lab], 1), axis=0)
    counts = np.bincount(fans[:, 0], minlength=num_verts)
    return np.flatnonzero(counts > 1)


def body_penetration(
    verts: np.ndarray, faces: np.ndarray, body_verts: np.ndarray, body_faces: np.ndarray
) -> tuple[np.ndarray, float]:
    """Signed vertex distances to a closed body [m] (V,) and the area share of garment faces
    whose centroid is inside the body (winding number; no margin)."""
    q = BodyDistance(body_verts, body_faces)
    d = q(verts)[0]
    dc = q(verts[faces].mean(1))[0]
    a = face_areas(verts, faces)
    return d, float(a[dc < 0].sum() / max(a.sum(), 1e-30))


def validate_garment(
    verts: np.ndarray,
    faces: np.ndarray,
    *,
    name: str = "garment",
    body: tuple | None | bool = None,
    margin: float = 2e-3,
    require_clearance: bool = True,
    check_self_intersections: bool = True,
    max_inside_area_fraction: float = 0.0,
) -> ValidationReport:
    """Check a garment template and report what is wrong with it.

    Args:
        verts: rest positions [m], shape (V, 3).
        faces: triangles, shape (F, 3) int.
        name: label used in messages.
        body: (body_verts, body_faces) to check against; None = the canonical body; False = skip.
        margin: collision margin [m] a template must keep from the body.
        require_clearance: vertices closer than `margin` (or inside) are errors (templates);
            when False only `max_inside_area_fraction` is enforced (loaded real garments).
        check_self_intersections: run the triangle-triangle test (Warp BVH).
        max_inside_area_fraction: allowed area share inside the body when not requiring clearance.

    Returns:
        the report. Malformed input arrays raise `GarmentError` right away.
    """
    verts = np.asarray(verts, np.float64)
    faces = np.asarray(faces)
    if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) == 0:
        raise GarmentError(f"{name}: vertices must have shape (V, 3) with V > 0, got {verts.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise GarmentError(f"{name}: faces must have shape (F, 3) with F > 0 (triangles), got {faces.shape}")
    if not np.issubdtype(faces.dtype, np.integer):
        raise GarmentError(f"{name}: face indices must be integers, got {faces.dtype}")
    faces = faces.astype(np.int64)
    bad = np.flatnonzero(~np.isfinite(verts).all(1))
    if bad.size:
        raise GarmentError(f"{name}: vertices {_show(bad)} have NaN/inf coordinates")
    out = np.flatnonzero(((faces < 0) | (faces >= len(verts))).any(1))
    if out.size:
        raise GarmentError(f"{name}: faces {_show(out)} index vertices outside [0, {len(verts)})")

    r = ValidationReport(name=name, num_verts=len(verts), num_faces=len(faces))
    used = np.unique(faces)
    r.extent = float((verts[used].max(0) - verts[used].min(0)).max())
    if r.extent > MAX_GARMENT_EXTENT_M:
        r.errors.append(
            f"the garment is {r.extent:.3g} units across: not metres (scale by 0.01 for cm, "
            "0.1 for dm, 0.001 for mm)"
        )
    unused = len(verts) - len(used)
    if unused:
        r.warnings.append(f"{unused} vertices are used by no face")
    e = undirected_edges(faces)
    lengths = np.linalg.norm(verts[e[:, 0]] - verts[e[:, 1]], axis=1)
    r.mean_edge, r.min_edge, r.max_edge = float(lengths.mean()), float(lengths.min()), float(lengths.max())
    r.euler = int(len(used) - len(e) + len(faces))
    r.non_manifold_edges = non_manifold_edges(faces)
    if len(r.non_manifold_edges):
        pairs = ", ".join(f"({a}, {b})" for a, b in r.non_manifold_edges[:8])
        r.errors.append(f"{len(r.non_manifold_edges)} edges are shared by more than two faces: {pairs}")
    r.non_manifold_verts = _non_manifold_verts(len(verts), faces)
    if len(r.non_manifold_verts):
        r.errors.append(f"non-manifold (bow-tie) vertices {_show(r.non_manifold_verts)}")
    lab = connected_components(len(verts), faces)
    r.num_components = int(len(np.unique(lab[used])))
    if r.num_components > 1:
        r.warnings.append(f"{r.num_components} connected components")
    if not len(r.non_manifold_edges):
        r.num_boundary_loops = len(boundary_loops(faces))
        if r.num_boundary_loops == 0:
            r.warnings.append("closed surface: a garment normally has open boundaries")
    he = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, hcount = np.unique(he, axis=0, return_counts=True)
    if (hcount > 1).any():
        r.warnings.append(
            f"{int((hcount > 1).sum())} edges join faces of opposite orientation (inconsistent "
            "winding): normals flip there; re-orient the faces (e.g. trimesh.repair.fix_winding)"
        )
    areas = face_areas(verts, faces)
    r.degenerate_faces = np.flatnonzero(areas < DEGENERATE_AREA_M2)
    if len(r.degenerate_faces):
        r.errors.append(f"degenerate (zero-area) faces {_show(r.degenerate_faces)}")
    tri = verts[faces]
    ang = []
    for k in range(3):
        u = tri[:, (k + 1) % 3] - tri[:, k]
        w = tri[:, (k + 2) % 3] - tri[:, k]
        c = (u * w).sum(1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1), 1e-30)
        ang.append(np.degrees(np.arccos(np.clip(c, -1, 1))))
    r.sliver_faces = np.flatnonzero(np.min(ang, 0) < SLIVER_ANGLE_DEG)
    if len(r.sliver_faces):
        r.warnings.append(f"{len(r.sliver_faces)} sliver faces (an angle < {SLIVER_ANGLE_DEG}°): {_show(r.sliver_faces)}")
    if check_self_intersections and not r.errors:
        r.self_intersecting_faces = self_intersecting_faces(verts, faces)
        if len(r.self_intersecting_faces):
            r.errors.append(f"self-intersecting faces {_show(r.self_intersecting_faces)}")
    if body is not False and r.extent <= MAX_GARMENT_EXTENT_M:
        if body is None:
            cb = canonical_body()
            body = (cb.verts, cb.faces)
        d, frac = body_penetration(verts, faces, *body)
        r.inside_verts = np.flatnonzero(d < 0)
        r.close_verts = np.flatnonzero((d >= 0) & (d < margin - 1e-5))
        r.min_clearance = float(d.min())
        r.inside_area_fraction = frac
        if require_clearance:
            if len(r.inside_verts):
                r.errors.append(f"vertices inside the body: {_show(r.inside_verts)}")
            if len(r.close_verts):
                r.errors.append(
                    f"vertices closer than the {margin * 1000:.1f} mm margin to the body: {_show(r.close_verts)}"
                )
        elif frac > max_inside_area_fraction:
            r.errors.append(
                f"{100 * frac:.2f} % of the area is inside the body (allowed "
                f"{100 * max_inside_area_fraction:.2f} %)"
            )
    return r
