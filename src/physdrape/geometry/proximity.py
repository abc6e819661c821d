"""Closest points, outward normals, signed distances and inside tests against posed bodies.

The collision handler (paper Eq. 11, DESIGN Sec. 3 step 6), the contact energy and the B2G
metric all ask the same question of many garment points: where is the closest point ``p`` on the
body *triangles* (exact point-triangle, not nearest vertex), which way is out there, how far is it
(signed), and is the point inside the body.

Split of the work:

1. **Search (not differentiated, `geometry.body_bvh`)**: NVIDIA Warp's triangle-mesh BVH
   (``wp.Mesh``, built once per body, ``refit()`` when only the vertex positions change) finds the
   closest triangle of every point in float32 and, if asked, the generalized winding number
   (Warp's fast winding number, Barill et al. 2018) for the inside test. Points that moved a
   little since an earlier query can instead walk from their earlier triangles to the closest
   ones around them (``query(near=...)``, `closest_point.walk_to_closest_faces`), in float64.
2. **Geometry (differentiable, float64, `geometry.closest_point`)**: the closest point on the
   found triangle is recomputed (Ericson's region test, a Warp kernel with its adjoint as the
   backward) in float64 and returned in the dtype of the input, so ``closest``,
   ``signed_distance`` and ``normal`` are differentiable w.r.t. the points and the body
   vertices; the pseudo-normal of the feature it lies on is read off its barycentrics in the
   same way.
3. **Inside test only where the sign is in doubt** (``SignMethod.WINDING_NUMBER``): the
   pseudo-normal sign of the closest feature is exact wherever the body surface around it is a
   clean, closed, consistently oriented sheet, and the winding number (about as costly as the
   closest-point search itself) is evaluated only for points whose closest face lies near where
   it is not: posed limbs that interpenetrate, or a hole in the mesh (see
   `BodySurface.doubtful_faces`).

Normal and sign (chosen so that the handler ``x* = x + delta * relu(eps - d) * n`` with
``delta >= 1`` puts every point at ``d >= eps`` wherever the body's local feature size exceeds
eps):

- ``s = -1`` if the point is inside the body, else ``+1`` (see ``SignMethod``).
- ``n = s * (x - p) / |x - p|`` when ``|x - p| > near_tol``: the gradient of the signed distance,
  valid whether the closest feature is a face, an edge or a vertex (a face normal would give a
  wrong distance and sometimes a wrong sign off edges and vertices).
- ``n =`` the angle-weighted pseudo-normal of the closest feature (face normal in a face, the mean
  of the two face normals on an edge, the angle-weighted vertex normal at a vertex, see
  `geometry.normals`) when the point is within ``near_tol`` of the surface, where ``x - p``
  carries no direction.
- ``d = (x - p) . n``, i.e. ``s * |x - p|`` away from the surface (exactly the signed distance) and
  ``|d| <= near_tol`` on it. Then ``p + eps * n`` is the handler's target for every point. Its
  distance to the body is exactly eps on convex parts; at a concave crease of angle theta between
  two triangles the neighbouring triangle can be up to eps * (1 - cos theta) closer (polyhedral
  limit: 30 micrometres for a 10-degree crease), which delta > 1 covers.
- ``closest`` and ``signed_distance`` are differentiable (exactly: the gradient of d w.r.t. x is
  n); ``normal`` is differentiable through ``x - p`` off the surface, the pseudo-normal is not.

World frame and units follow DESIGN Sec. 1 (metres); no dtype is hard-coded.
"""

from __future__ import annotations

import enum
import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from physdrape.geometry.body_bvh import BodyBVH
from physdrape.geometry.closest_point import (
    SurfaceArrays,
    closest_surface_points,
    walk_to_closest_faces,
)
from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.doubtful_faces import DOUBT_REACH, doubtful_faces
from physdrape.geometry.normals import vertex_face_table
from physdrape.geometry.query_inputs import check_faces, check_verts, packed_points
from physdrape.geometry.surface_normals import surface_normals
from physdrape.geometry.topology import boundary_edges, edge_neighbour_faces, face_rings

__all__ = [
    "DOUBT_REACH",
    "BodySurface",
    "SignMethod",
    "SurfaceQuery",
    "query_body_surface",
]


class SignMethod(str, enum.Enum):
    """How a point is classified as inside the body.

    WINDING_NUMBER: generalized winding number > 0.5 (Warp's fast winding number). Robust to
        holes, flipped patches and self-intersections (overlapping limbs count as inside). Default.
        Evaluated where the pseudo-normal sign is in doubt (`BodySurface.doubtful_faces`); elsewhere
        the two agree and the cheaper pseudo-normal sign is taken.
        Where limbs interpenetrate, a point inside the torso may get its closest point on the
        arm's surface: d < 0 is then right, but n points through the arm (no single outward
        direction exists there).
    PSEUDO_NORMAL: sign of ``(x - p) . n_pseudo`` at the closest feature (Baerentzen & Aanaes
        2005). Exact for closed, consistently oriented, non-self-intersecting surfaces and
        cheaper (no winding-number pass per query, a cheaper refit); wrong where posed limbs
        interpenetrate or the mesh has holes.
    """

    WINDING_NUMBER = "winding_number"
    PSEUDO_NORMAL = "pseudo_normal"


@functools.lru_cache(maxsize=8)
def _body_topology(faces: bytes, num_faces: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per body topology (computed once per mesh): each face's neighbours across its edges (F, 3),
    the vertices on a hole's border and each face's ring of faces that share a vertex with it
    (F, W) int32, padded with F (what `walk_to_closest_faces` reads)."""
    tri = np.frombuffer(faces, dtype=np.int64).reshape(num_faces, 3)
    around = vertex_face_table(torch.from_numpy(tri.copy()), int(tri.max()) + 1 if num_faces else 0).numpy()
    return edge_neighbour_faces(tri), np.unique(boundary_edges(tri)), face_rings(tri, around).astype(np.int32)


@dataclass(frozen=True)
class SurfaceQuery:
    """Result of a body-surface query; ``...`` is the leading shape of the query points.

    Attributes:
        closest: closest point p on the body triangles [m], shape (..., 3); differentiable.
        normal: unit outward direction n at p (see the module docstring), shape (..., 3).
        signed_distance: d = (x - p) . n [m], negative inside the body, shape (...).
        face: index of the triangle holding p, shape (...) int64.
        bary: barycentric coordinates of p in that triangle, shape (..., 3); sum to 1.
        inside: True where the point is inside the body, shape (...) bool.
    """

    closest: Tensor
    normal: Tensor
    signed_distance: Tensor
    face: Tensor
    bary: Tensor
    inside: Tensor


# --------------------------------------------------------------------------------------------
# BodySurface
# --------------------------------------------------------------------------------------------


class BodySurface:
    """A batch of posed bodies sharing one triangle topology, ready for many point queries.

    Build once per body topology; call ``update(verts)`` when the bodies move (BVH refit, no
    rebuild); then ``query(points)`` as often as needed.

    Args:
        verts: body vertex positions [m], shape (Vb, 3) or (B, Vb, 3); kept (not copied) so the
            query results are differentiable w.r.t. them. The surface, its BVHs and its searches
            live on their device (CPU or CUDA); queries take points on that device.
        faces: outward-wound (counter-clockwise seen from outside) triangles, shape (Fb, 3) int.
        sign_method: how ``inside`` (and so the sign of d) is decided; see ``SignMethod``.
        near_tol: distance [m] below which a point counts as on the surface and gets the
            pseudo-normal of its closest feature instead of the direction of ``x - p``.
        search_threads: CPU threads that share the BVH search of one query (Warp's CPU kernels
            are serial; the points are split into chunks launched from a thread pool, bit-for-bit
            the same result). None = torch's thread count (`torch.get_num_threads()`).
        winding_accuracy: Warp's fast-winding-number accuracy (its ``beta``: a BVH node is
            replaced by its dipole expansion when farther than beta times its radius; larger is
            more exact and slower). 1.0 gives the same inside flags on the closed Anny body as
            2.0 (Warp's default), 4.0 and the brute-force winding number, at less cost; values
            below 1 misclassify points near the body and are refused.
    """

    def __init__(
        self,
        verts: Tensor,
        faces: Tensor | np.ndarray,
        *,
        sign_method: SignMethod | str = SignMethod.WINDING_NUMBER,
        near_tol: float = 1e-6,
        winding_accuracy: float = 1.0,
        search_threads: int | None = None,
    ) -> None:
        self.sign_method = SignMethod(sign_method)
        if search_threads is not None and search_threads < 1:
            raise ValueError(f"search_threads must be >= 1 or None, got {search_threads}")
        self.search_threads = search_threads
        if not near_tol > 0:
            raise ValueError(f"near_tol must be > 0, got {near_tol}")
        if not winding_accuracy >= 1.0:
            raise ValueError(f"winding_accuracy must be >= 1 (got {winding_accuracy}); "
                             "smaller values misclassify points near the body")
        self.near_tol = float(near_tol)
        self.winding_accuracy = float(winding_accuracy)
        verts = check_verts(verts)
        self.faces = check_faces(faces, verts.shape[1], verts.device)
        self._faces32 = self.faces.to(torch.int32).contiguous()  # what the kernels read
        edge_nbr, border, rings = _body_topology(self.faces.cpu().numpy().tobytes(), self.faces.shape[0])
        self._edge_nbr = torch.from_numpy(edge_nbr).to(device=verts.device, dtype=torch.int32)
        self._border = torch.from_numpy(border).to(verts.device)
        self._rings = torch.from_numpy(rings).to(verts.device)
        self._build(verts)

    # -- structure ---------------------------------------------------------------------------

    @property
    def batch_size(self) -> int:
        return self.verts.shape[0]

    @property
    def num_verts(self) -> int:
        return self.verts.shape[1]

    @property
    def num_faces(self) -> int:
        return self.faces.shape[0]

    @property
    def device(self) -> torch.device:
        return self.verts.device

    def to(self, device: torch.device | str) -> BodySurface:
        """The same surface (same settings) on `device`: itself when already there, else a new
        one with its BVHs built there."""
        verts = self.verts.to(device)
        if verts is self.verts:
            return self
        return BodySurface(verts, self.faces.to(device), sign_method=self.sign_method,
                           near_tol=self.near_tol, winding_accuracy=self.winding_accuracy,
                           search_threads=self.search_threads)

    def select(self, index: int) -> BodySurface:
        """Body `index` alone as a surface of one body (same settings), sharing this surface's BVH
        and what it has found of its doubtful faces: nothing is built. Do not `update` either
        while the other is in use."""
        one = object.__new__(BodySurface)
        one.sign_method, one.search_threads = self.sign_method, self.search_threads
        one.near_tol, one.winding_accuracy = self.near_tol, self.winding_accuracy
        one.faces, one._faces32, one._edge_nbr, one._border = self.faces, self._faces32, self._edge_nbr, self._border
        one._rings = self._rings
        one.verts = self.verts[index:index + 1]
        one._verts64 = None
        one._vertex_normals = None if self._vertex_normals is None else self._vertex_normals[index:index + 1]
        one._face_normals = None if self._face_normals is None else tuple(n[index:index + 1] for n in self._face_normals)
        one._doubtful = None if self._doubtful is None else self._doubtful[index:index + 1]
        one._points_asked = self._points_asked
        one._bvh = self._bvh.select(index)
        one._selected_from = (self, index)
        return one

    def _build(self, verts: Tensor) -> None:
        """(Re)build one Warp BVH per body."""
        self.verts = verts
        self._verts64 = None
        self._vertex_normals = None
        self._face_normals = None
        self._doubtful = None
        self._points_asked = 0
        self._selected_from: tuple[BodySurface, int] | None = None
        self._bvh = BodyBVH(verts, self.faces, with_winding_number=self.sign_method is SignMethod.WINDING_NUMBER)

    def update(self, verts: Tensor) -> None:
        """Move the bodies to new vertex positions (same topology): refit the BVHs.

        Args:
            verts: new positions [m], shape (Vb, 3) or (B, Vb, 3). A different B rebuilds.
        """
        verts = check_verts(verts)
        if verts.shape[1] != self.num_verts:
            raise ValueError(f"update() got {verts.shape[1]} vertices per body, the surface has {self.num_verts}; "
                             "a different topology needs a new BodySurface")
        if verts.shape[0] != self.batch_size or verts.device != self.verts.device:
            self._build(verts)
            return
        self.verts = verts
        self._verts64 = None
        self._vertex_normals = None
        self._face_normals = None
        self._doubtful = None
        self._bvh.refit(verts)

    @classmethod
    def from_body_state(cls, state, **kwargs) -> BodySurface:
        """Build from a ``physdrape.body.model.BodyState`` (its verts and faces)."""
        return cls(state.verts, state.faces, **kwargs)

    # -- queries -----------------------------------------------------------------------------

    def search(self, points32: Tensor, body: Tensor, *, winding: bool = False) -> tuple[Tensor, Tensor | None]:
        """Warp BVH search: closest face (M,) int64 (and, with `winding`, the winding-number inside
        flag (M,) bool) of points32 (M, 3) float32 of bodies `body` (M,) int32, both contiguous."""
        return self._bvh.closest_faces(points32, body, winding_accuracy=self.winding_accuracy,
                                       threads=self.search_threads, winding=winding)

    @torch.no_grad()
    def doubtful_faces(self) -> Tensor:
        """Faces near which the pseudo-normal sign may be wrong, shape (B, Fb) bool
        (`geometry.doubtful_faces`); computed once per body position (until `update`)."""
        if self._doubtful is not None:
            return self._doubtful
        if self._selected_from is not None:  # found once for the whole batch
            batch, index = self._selected_from
            self._doubtful = batch.doubtful_faces()[index:index + 1]
            return self._doubtful
        if self.sign_method is not SignMethod.WINDING_NUMBER:
            raise ValueError("doubtful_faces needs sign_method=WINDING_NUMBER")
        self._doubtful = doubtful_faces(self.verts.detach(), self.faces, self._vertex_pseudo_normals(), self._border,
                                        self._bvh, threads=self.search_threads,
                                        winding_accuracy=self.winding_accuracy)
        return self._doubtful

    def expect(self, points: int) -> None:
        """Say that about `points` more points will be asked about (a caller that knows its
        workload): when their winding numbers would cost more than finding the doubtful faces
        (one winding number per body vertex), the doubtful faces are found now, and the points
        asked from here on get the winding number only where the sign is in doubt."""
        if (self.sign_method is SignMethod.WINDING_NUMBER and self._doubtful is None
                and self._points_asked + points >= self.verts.shape[0] * self.verts.shape[1]):
            self.doubtful_faces()

    def forget_recent(self) -> None:
        """Drop the searches kept for reuse (`BodyBVH.closest_faces`): the next query of each
        size searches every point."""
        self._bvh.forget_recent()

    def _vertex_pseudo_normals(self) -> Tensor:
        """Angle-weighted vertex normals of all bodies, shape (B, Vb, 3), in the bodies' dtype;
        cached until update()."""
        if self._vertex_normals is None:
            self._vertex_normals = self._feature_normals()[2].to(self.verts.dtype)
        return self._vertex_normals

    def _feature_normals(self) -> tuple[Tensor, Tensor, Tensor]:
        """Unit normals of all bodies' faces (B, Fb, 3), edges (B, Fb, 3, 3) and vertices (B, Vb,
        3), float64 (what the pseudo-normal kernel reads; `geometry.surface_normals`): face f's
        edge opposite its corner k at [:, f, k], the normalised sum of the normals of the two
        faces that share it (the face's own on a hole's border); the vertices' angle-weighted;
        cached until update()."""
        if self._face_normals is None:
            self._face_normals = surface_normals(self.verts, self._faces32, self._edge_nbr)
        return self._face_normals

    def _flat_verts64(self) -> Tensor:
        """All bodies' vertices flattened to (B·Vb, 3) float64, what the closest-point kernel reads:
        a copy kept until `update`, or, while the vertices take part in a graph, made per call
        (differentiable)."""
        if self.verts.requires_grad and torch.is_grad_enabled():
            return self.verts.reshape(-1, 3).to(torch.float64).contiguous()
        if self._verts64 is None:
            self._verts64 = self.verts.detach().reshape(-1, 3).to(torch.float64).contiguous()
        return self._verts64

    def query(self, points: Tensor, *, body_index: Tensor | None = None, near: Tensor | None = None,
              bound: DistanceBound | None = None) -> SurfaceQuery:
        """Closest point, outward normal, signed distance and inside flag of many points.

        Args:
            points: query points [m], shape (B, N, 3) (one row of points per body), or packed
                (N, 3) with ``body_index``, or (N, 3) when the surface holds one body. Same dtype
                as the body verts.
            body_index: for packed points, which body each point belongs to, shape (N,) int.
            near: a triangle of each point's body to walk from, leading shape
                ``points.shape[:-1]`` int (the ``face`` of an earlier query of the points, a small
                move ago): the closest triangle is then found by the local walk from it
                (`closest_point.walk_to_closest_faces`), not by the BVH search of the whole
                surface. None: the BVH search.
            bound: an earlier exact query's `DistanceBound` of the same points (a row per point,
                in the flattened order): a point in doubt that cannot have crossed the surface
                since (`DistanceBound.sign`) keeps its side, without a winding number.

        Returns:
            A ``SurfaceQuery`` whose fields have the leading shape ``points.shape[:-1]``.
        """
        x, body, lead = packed_points(points, body_index, self.verts)
        if near is not None:
            near = self._start_faces(near, lead)
        x64 = x.to(torch.float64).contiguous()
        with torch.no_grad():
            x32 = x.detach().to(torch.float32).contiguous()
            body32 = body.to(torch.int32).contiguous()
            if near is None:
                face = self._bvh.closest_faces(x32, body32, winding_accuracy=self.winding_accuracy,
                                               threads=self.search_threads, reuse=True)[0]
            else:
                face = walk_to_closest_faces(x64.detach(), self._flat_verts64().detach(), body32, near,
                                             self._faces32, self._rings, num_verts=self.num_verts).to(torch.int64)

        on = closest_surface_points(x64, self._flat_verts64(), body32,
                                    face.to(torch.int32).contiguous(), self._faces32, *self._feature_normals(),
                                    near_tol=self.near_tol)
        inside, n, d = on.inside, on.normal, on.signed_distance  # the pseudo-normal's sign
        known = None if bound is None else (lambda rows: bound.select(rows).sign(x64[rows]))
        sign = self.winding_sign(x32.__getitem__, body32, face, inside, on.near, known=known)
        if sign is not None:
            doubt, inside_doubt, flip_doubt = sign
            with torch.no_grad():
                flip = torch.ones_like(d)
                flip[doubt] = flip_doubt.to(flip.dtype)
                inside = inside.clone()
                inside[doubt] = inside_doubt
            n, d = n * flip[:, None], d * flip
        p, bary = on.closest.to(x.dtype), on.bary.to(x.dtype)
        n, d = n.to(x.dtype), d.to(x.dtype)
        return SurfaceQuery(
            closest=p.reshape(*lead, 3),
            normal=n.reshape(*lead, 3),
            signed_distance=d.reshape(lead),
            face=face.reshape(lead),
            bary=bary.reshape(*lead, 3),
            inside=inside.reshape(lead),
        )

    def query_within(self, points: Tensor, threshold: float, *, body_index: Tensor,
                     bound: DistanceBound | None) -> tuple[Tensor | None, SurfaceQuery]:
        """`query` of those of the packed points (N, 3) (bodies `body_index` (N,)) that may lie
        within `threshold` [m] of the body by `bound`, a `DistanceBound` of these points row by
        row (whose sides also decide the points in doubt that cannot have crossed the surface):
        the rows asked (int64; None without a bound: every point) and their query."""
        if bound is None:
            return None, self.query(points, body_index=body_index)
        rows = bound.rows_below(points, threshold)
        return rows, self.query(points[rows], body_index=body_index[rows], bound=bound.select(rows))

    def found_doubtful_faces(self) -> Tensor | None:
        """The doubtful faces (B, Fb) bool where this surface has found them already (the same
        tensor until `update`), else None (not yet, or the pseudo-normal sign only)."""
        return self._doubtful if self.sign_method is SignMethod.WINDING_NUMBER else None

    @torch.no_grad()
    def in_doubt(self, face: Tensor, body: Tensor) -> Tensor:
        """Whether the pseudo-normal sign is in doubt (`query` takes the winding number) at points
        whose closest faces are `face` of bodies `body`, (M,) int each → (M,) bool: near a doubtful
        face; or every point while this surface has been asked about fewer points than its bodies
        have vertices (finding the doubtful faces costs a winding number per body vertex: until
        then the winding number of every point is cheaper). Counts the M points as asked."""
        self._points_asked += face.shape[0]
        if self._doubtful is None and self._points_asked < self.verts.shape[0] * self.verts.shape[1]:
            return torch.ones(face.shape, dtype=torch.bool, device=face.device)
        return self.doubtful_faces()[body.long(), face.long()]

    @torch.no_grad()
    def winding_sign(self, points32: Callable[[Tensor], Tensor], body: Tensor, face: Tensor, inside: Tensor,
                     near: Tensor, *, known: Callable[[Tensor], Tensor] | None = None
                     ) -> tuple[Tensor, Tensor, Tensor] | None:
        """The winding number's sign where the pseudo-normal's is in doubt (`in_doubt`), for M
        points of bodies `body` (M,) int32 whose closest faces are `face` (M,), and whose closest
        points' pseudo-normals call them `inside` (M,) bool, within near_tol of the surface where
        `near` (M,) bool; points32(rows) gives the rows' points (R, 3) float32 (formed only for the
        rows in doubt); known(rows), if given, the side each of those rows must be on (R,) int8
        (+1 outside, −1 inside, 0 unknown: `DistanceBound.sign`), which the rows it knows take
        instead of a winding number. Returns the rows in doubt, their inside flags (the winding
        number's, or known) and their sign flips (−1 where that flag disagrees off the surface: the
        normal and the signed distance change sign; +1 elsewhere), or None with
        ``SignMethod.PSEUDO_NORMAL`` or no row in doubt."""
        if self.sign_method is not SignMethod.WINDING_NUMBER:
            return None
        doubt = torch.nonzero(self.in_doubt(face, body))[:, 0]
        if not doubt.numel():
            return None
        side = torch.zeros(doubt.shape, dtype=torch.int8, device=doubt.device) if known is None else known(doubt)
        unknown = side == 0
        wn_inside = side < 0
        if bool(unknown.any()):
            ask = doubt[unknown]
            wn_inside[unknown] = self.search(points32(ask).contiguous(), body[ask].contiguous(), winding=True)[1]
        # off the surface the normal points away from the inside
        flip = 1 - 2 * ((wn_inside != inside[doubt]) & ~near[doubt]).to(torch.int8)
        return doubt, wn_inside, flip

    def walk_arrays(self) -> SurfaceArrays:
        """The arrays a kernel that walks over these bodies and projects onto them reads
        (`closest_point.SurfaceArrays`; not differentiated)."""
        return SurfaceArrays(self._flat_verts64().detach(), self._faces32, self._rings, *self._feature_normals(),
                             self.num_verts, self.near_tol)

    def _start_faces(self, near: Tensor, lead: tuple) -> Tensor:
        """`query`'s `near` checked (one body face per point) and flattened to int32."""
        if tuple(near.shape) != tuple(lead) or near.is_floating_point():
            raise ValueError(f"near must hold one body face index per point, shape {tuple(lead)} int; got "
                             f"{tuple(near.shape)} {near.dtype}")
        flat = near.reshape(-1).to(torch.int32).contiguous()
        if flat.numel() and (int(flat.min()) < 0 or int(flat.max()) >= self.num_faces):
            raise ValueError(f"near's face indices must be in [0, {self.num_faces}) (got {int(flat.min())} to "
                             f"{int(flat.max())}): pass the `face` of an earlier query of this surface")
        return flat

    @torch.no_grad()
    def inside(self, points: Tensor, *, body_index: Tensor | None = None) -> Tensor:
        """Whether each point is inside the body, by the winding number of every point (the
        `inside` of `query` before the surface has found its doubtful faces), without the closest
        points and normals: for a check that asks about a few points once. Arguments and leading
        shape as `query`; needs ``SignMethod.WINDING_NUMBER``."""
        if self.sign_method is not SignMethod.WINDING_NUMBER:
            raise ValueError("inside() needs sign_method=WINDING_NUMBER")
        x, body, lead = packed_points(points, body_index, self.verts)
        inside = self.search(x.to(torch.float32).contiguous(), body.to(torch.int32).contiguous(), winding=True)[1]
        return inside.reshape(lead)


def query_body_surface(
    points: Tensor,
    verts: Tensor,
    faces: Tensor | np.ndarray,
    *,
    body_index: Tensor | None = None,
    **kwargs,
) -> SurfaceQuery:
    """One-off query: build a ``BodySurface`` and query it (see both for arguments and shapes)."""
    return BodySurface(verts, faces, **kwargs).query(points, body_index=body_index)
