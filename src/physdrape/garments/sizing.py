"""Sizing: the rest shape a garment has on a body of another shape than the one it was made on.

A drape's physics measures stretch against the garment's rest shape. Two answers are useful:

- ``fixed``: the template's own rest shape, whatever the body (virtual try-on: a size M stays a
  size M; on a slim body it is loose and nothing but the shoulders and hips hold it up, on a heavy
  one it is tight);
- ``fit``: a rest shape that follows the body's shape, so a garment authored on one body is
  worn at the same place on another, as MakeHuman refits its clothes. For an ``.mhclo`` garment
  it comes from the garment's binding to the body (`MhcloSizer`); for any other garment from the
  skinning transfer's shape part (X_temp + ΔX_shape, `body.skinning_transfer`).

`MhcloSizer` carries the binding over to the remeshed template: each template vertex is tied to
its closest point on the original `.mhclo` mesh on the canonical body (a triangle and barycentric
coordinates), and follows that point's displacement when the garment is refitted onto another
body. Where neighbouring template vertices are tied to parts of the original mesh that move
differently (a collar's fold on a body far from the canonical one), a face can collapse to a
sliver, whose rest shape would make it the stiffest element of the drape by orders of magnitude:
the displacement is smoothed over the vertices of such faces until each keeps at least
`MIN_AREA_RATIO` of its template area (`relax_collapsed_faces`). Like `load_mhclo`, vertices
inside the target body or closer than the margin are then pushed out to it.
"""

from __future__ import annotations

import enum
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from physdrape.body.anny_body import get_anny_body
from physdrape.garments.mhclo import fit_mhclo, read_mhclo, resolve_body_penetration
from physdrape.geometry.closest_point import closest_point_on_triangle
from physdrape.geometry.mesh import face_areas, read_obj
from physdrape.geometry.topology import undirected_edges, vertex_adjacency

__all__ = ["MIN_AREA_RATIO", "MhcloSizer", "Sizing", "default_sizing", "relax_collapsed_faces",
           "triangle_coordinates"]

#: Least share of its template area a face keeps in a refitted rest shape (`relax_collapsed_faces`).
MIN_AREA_RATIO = 0.3


class Sizing(str, enum.Enum):
    """How a garment's rest shape follows the body (module docstring)."""

    FIT = "fit"
    FIXED = "fixed"


def default_sizing(sizer) -> Sizing:
    """The default of a garment: FIT where it carries a MakeHuman binding (`sizer` not None:
    MakeHuman clothes are made to follow every body, and users of them expect that), FIXED for a
    mesh (a garment of one size, tried on)."""
    return Sizing.FIT if sizer is not None else Sizing.FIXED


def triangle_coordinates(points: np.ndarray, verts: np.ndarray, faces: np.ndarray, *,
                         candidates: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """The closest point on a triangle mesh of each point, as a triangle and barycentric coordinates.

    The exact closest point among the `candidates` triangles with the nearest centroids (exact
    for meshes of even triangles, which the MakeHuman meshes are).

    Args:
        points: (N, 3) [m]; verts: mesh vertices (Vm, 3) [m]; faces: (Fm, 3) int.

    Returns:
        face (N,) int64 and bary (N, 3) float64 (sum to 1).
    """
    p = np.asarray(points, np.float64)
    v = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    k = min(candidates, len(f))
    _, near = cKDTree(v[f].mean(1)).query(p, k=k)
    near = near.reshape(len(p), k)
    tri = torch.from_numpy(v[f[near]])  # (N, k, 3 corners, 3)
    x = torch.from_numpy(p)[:, None, :].expand(-1, k, -1)
    closest, bary = closest_point_on_triangle(x, tri[:, :, 0], tri[:, :, 1], tri[:, :, 2])
    best = (closest - x).norm(dim=-1).argmin(dim=1)
    rows = torch.arange(len(p))
    return near[rows.numpy(), best.numpy()].astype(np.int64), bary[rows, best].numpy()


@dataclass(eq=False)
class MhcloSizer:
    """Refits an `.mhclo` garment's remeshed template onto any Anny phenotype (module docstring).

    Args:
        path: the `.mhclo` file.
        template_verts: the template on the canonical body [m] (V, 3) (`load_mhclo`: refitted,
            remeshed, pushed out of the body).
        faces: the template's triangles (F, 3).
        margin: clearance kept from the target body [m] (`resolve_body_penetration`).
    """

    path: Path
    template_verts: np.ndarray
    faces: np.ndarray
    margin: float = 2e-3
    _tie: tuple | None = field(default=None, repr=False)

    @staticmethod
    def for_file(path: str | os.PathLike, template_verts: np.ndarray, faces: np.ndarray) -> MhcloSizer:
        return MhcloSizer(Path(path), np.asarray(template_verts, np.float64), np.asarray(faces, np.int64))

    def _binding(self):
        """(binding, original faces, original mesh on the canonical body, face and bary per
        template vertex), computed once."""
        if self._tie is None:
            binding = read_mhclo(self.path)
            _, obj_faces = read_obj(binding.obj_file)
            obj_faces = np.asarray(obj_faces, np.int64)
            canonical = fit_mhclo(binding, _hm08(None))
            face, bary = triangle_coordinates(self.template_verts, canonical, obj_faces)
            self._tie = (binding, obj_faces, canonical, face, bary)
        return self._tie

    def rest(self, shape: torch.Tensor | None) -> np.ndarray:
        """The garment's rest shape on the Anny body of phenotypes `shape` (1, 6) (None: the
        canonical body), rest pose [m], (V, 3) float64."""
        binding, obj_faces, canonical, face, bary = self._binding()
        hm08 = _hm08(shape)
        displacement = fit_mhclo(binding, hm08) - canonical  # (Vo, 3)
        corners = obj_faces[face]  # (V, 3)
        x = self.template_verts + (displacement[corners] * bary[:, :, None]).sum(1)
        x = relax_collapsed_faces(self.template_verts, x, self.faces)
        anny = get_anny_body()
        x, _ = resolve_body_penetration(x, self.faces, hm08[anny.hm08_ids.numpy()], anny.faces.numpy(),
                                        margin=self.margin)
        return x


def relax_collapsed_faces(template: np.ndarray, x: np.ndarray, faces: np.ndarray, *,
                          rounds: int = 50) -> np.ndarray:
    """x (V, 3) [m], a moved copy of `template` (V, 3), with its displacement x − template
    replaced by the mean of the neighbours' at the vertices of every face that kept less than
    `MIN_AREA_RATIO` of its template area, and their neighbours (Jacobi rounds until no face is
    below, at most `rounds`): the template's own shape comes back there, carried by the smooth
    displacement around it. Faces away from the collapsed ones keep theirs exactly."""
    template, faces = np.asarray(template, np.float64), np.asarray(faces, np.int64)
    rest = np.maximum(face_areas(template, faces), np.finfo(np.float64).tiny)
    disp = np.array(x, np.float64) - template
    adjacency = vertex_adjacency(len(template), undirected_edges(faces))
    degree = np.maximum(np.asarray(adjacency.sum(1)).ravel(), 1.0)
    for _ in range(rounds):
        collapsed = face_areas(template + disp, faces) < MIN_AREA_RATIO * rest
        if not collapsed.any():
            break
        region = np.zeros(len(template), bool)
        region[faces[collapsed].ravel()] = True
        region |= (adjacency @ region.astype(np.float64)) > 0  # and their neighbours
        mean = (adjacency @ disp) / degree[:, None]
        disp[region] = mean[region]
    return template + disp


def _hm08(shape: torch.Tensor | None) -> np.ndarray:
    """The Anny body of phenotypes `shape` (1, 6) (None: canonical) on hm08, rest pose [m], (19158, 3)."""
    anny = get_anny_body()
    with torch.no_grad():
        s = anny.default_shape(1, dtype=torch.float64) if shape is None else shape.to(torch.float64).reshape(1, -1)
        return anny.hm08_verts(s)[0].numpy()
