"""Body contact: the penalty E_c = k_c Σ_s ReLU(ε − d_s)³ on the garment's contact samples.

The samples are the garment's vertices, then its face centroids: S = V + F points, packed in that
order. With vertices alone a face lying on a convex part of the body (a shoulder, an arm) dips
its middle inside while its corners sit in the margin, and B2G counts faces by their centroids.
A centroid moves with its face's corners (c = (x_a + x_b + x_c) / 3), so its force is shared
equally by them.

d_s is the signed distance of sample s to the body surface along the outward normal n_s [m]:
either from a body query, or from a closest-point plane held fixed (d = (s − p)·n). In both cases
∇_s d = n, so the gradient onto the vertices is exact, and with the plane held fixed the
Gauss–Newton blocks 6 k_c ReLU(ε − d) n nᵀ are the exact Hessian.

Every user (the training loss, the stretching solver, the physics oracle, the evaluation's
total energy) calls these functions with its own stiffness k_c [J/m³] and margin ε [m]. The
distances, forces and blocks on planes (`plane_distance`, `plane_contact_forces`,
`plane_contact_blocks`) are Warp kernels (`physics.contact_kernels`), whose per-sample functions
the stretching solver's one launch per step composes with the garment's own terms
(`physics.potential.GarmentPotential.local_terms`); training differentiates `plane_contact_forces`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from typing import TYPE_CHECKING

import torch
from torch import Tensor

from physdrape.geometry.closest_point import WALK_MOVES
from physdrape.geometry.distance_bound import SLACK as DISTANCE_SLACK
from physdrape.geometry.proximity import SignMethod, SurfaceQuery
from physdrape.physics import contact_kernels
from physdrape.physics.element_kernels import run_kernel
from physdrape.tensor_memo import TensorMemo
from physdrape.warp_runtime import launch_arg, torch_stream, warp

if TYPE_CHECKING:
    from physdrape.geometry.distance_bound import DistanceBound
    from physdrape.geometry.proximity import BodySurface
    from physdrape.physics.cloth import Cloth

#: Collision margin ε [m]; also the collision handler's margin (DESIGN.md Sec. 2).
DEFAULT_MARGIN = 2e-3
#: Penalty stiffness k_c [J/m³] (DESIGN.md Sec. 2).
DEFAULT_STIFFNESS = 2.5e3


def contact_samples(x: Tensor, faces: Tensor) -> Tensor:
    """The contact samples of positions x (V, 3) [m]: the vertices, then the face centroids, (V + F, 3)."""
    # three row gathers by index_select (the solver forms the samples several times per step):
    # half the cost of indexing x[faces[:, k]], a third of gathering (F, 3, 3) and reducing it;
    # same sum, same order
    corners = [x.index_select(0, faces[:, k]) for k in range(3)]
    return torch.cat([x, (corners[0] + corners[1] + corners[2]) / 3.0])


def samples_at(x: Tensor, faces: Tensor, rows: Tensor) -> Tensor:
    """`contact_samples`(x, faces)[rows] (R, 3) without forming the other samples: rows (R,) int
    index the V + F samples (a vertex below V, a face's centroid from V on)."""
    num_verts = x.shape[0]
    face = (rows - num_verts).clamp_min(0)
    corners = faces.index_select(0, face)
    centroid = (x.index_select(0, corners[:, 0]) + x.index_select(0, corners[:, 1])
                + x.index_select(0, corners[:, 2])) / 3.0
    return torch.where((rows < num_verts)[:, None], x.index_select(0, rows.clamp_max(num_verts - 1)), centroid)


def sample_index(per_vertex: Tensor, faces: Tensor) -> Tensor:
    """A per-vertex label (V,) (garment, body) extended to the samples (V + F,): a centroid takes
    its face's first corner's."""
    return torch.cat([per_vertex, per_vertex[faces[:, 0]]])


def query_samples(x: Tensor, faces: Tensor, bodies: BodySurface, vert_body: Tensor | None, *,
                  rows: Tensor | None = None, near: Tensor | None = None,
                  bound: DistanceBound | None = None) -> SurfaceQuery:
    """Body query of the samples of x (V, 3) [m], each against its vertex's body vert_body (V,)
    (None: the surface holds one body); rows: only these samples (indices into the V + F); near:
    a body triangle per queried sample to walk from instead of the BVH search; bound: an earlier
    exact query's bound of the V + F samples, which decides the side of those in doubt that cannot
    have crossed the surface since (`BodySurface.query`).

    The samples are formed in the body's dtype; the query's fields have leading shape (V + F,),
    or that of rows.
    """
    samples = contact_samples(x.to(bodies.verts.dtype), faces)
    index = None if vert_body is None else sample_index(vert_body, faces)
    if rows is not None:
        samples, index = samples[rows], None if index is None else index[rows]
        bound = None if bound is None else bound.select(rows)
    return bodies.query(samples, body_index=index, near=near, bound=bound)


def query_samples_near(x: Tensor, faces: Tensor, bodies: BodySurface, vert_body: Tensor | None, *,
                       reach: float) -> SurfaceQuery:
    """`query_samples` of x (V, 3) [m] where only the planes within `reach` [m] of the body matter:
    every vertex is queried, a face centroid only where its distance may be below `reach` by its
    corners' (a signed distance is 1-Lipschitz: d(c) ≥ d(v) − ‖c − v‖). A centroid beyond gets a
    stand-in plane at that lower bound below it (normal +y, face −1, outside): a contact term or
    block that ignores samples at least `reach` from their planes sees nothing of it, as it would
    see nothing of its own plane. Its signed_distance is the bound, not the distance."""
    samples = contact_samples(x.to(bodies.verts.dtype), faces)
    num_verts = x.shape[0]
    vertex = bodies.query(samples[:num_verts], body_index=vert_body)
    centroid = samples[num_verts:]
    gap = (centroid[:, None, :] - samples[:num_verts][faces]).norm(dim=-1)
    lower = (vertex.signed_distance[faces] - gap).amax(dim=1)
    near = torch.nonzero(lower < reach + DISTANCE_SLACK)[:, 0]
    found = bodies.query(centroid[near], body_index=None if vert_body is None else vert_body[faces[near, 0]])
    normal = torch.zeros_like(centroid)
    normal[:, 1] = 1.0
    parts = {"closest": centroid - lower[:, None] * normal, "normal": normal, "signed_distance": lower,
             "face": torch.full_like(lower, -1, dtype=torch.int64), "bary": torch.full_like(centroid, 1.0 / 3.0),
             "inside": torch.zeros_like(lower, dtype=torch.bool)}
    fields = {}
    for name, stand_in in parts.items():
        value = getattr(found, name)
        fields[name] = torch.cat([getattr(vertex, name), stand_in.to(value.dtype).index_copy(0, near, value)])
    return SurfaceQuery(**fields)


@dataclass(frozen=True)
class FollowedPlanes:
    """The samples' planes after `follow_planes`, (V + F, ...) each: closest points and unit
    normals (float64), body faces (int64), where each sample was when its plane was found
    (float64), and the change of the penalty k_c ReLU(ε − d)³ at the sample [J] that its new
    plane makes (float64; 0 where the plane was kept)."""

    closest: Tensor
    normal: Tensor
    face: Tensor
    found_at: Tensor
    change: Tensor


def follow_planes(x: Tensor, faces: Tensor, closest: Tensor, normal: Tensor, face: Tensor, found_at: Tensor,
                  bodies: BodySurface, vert_body: Tensor | None, *, band: float, min_move: float, stiffness: float,
                  margin: float) -> FollowedPlanes:
    """The held planes of the samples of x (V, 3) [m] that lie closer to their plane (closest,
    normal, (V + F, 3)) than `band` [m] found again: the closest body face by a walk from the
    plane's body face (`face`, (V + F,)), and the closest point and normal there, as
    `BodySurface.query(near=...)` finds them, in one launch for all samples. With min_move > 0
    [m] only the samples that also moved farther than that since they were at `found_at` (V + F,
    3) follow. vert_body: each vertex's body (V,) (None: the surface holds one body).

    Where the pseudo-normal's sign is in doubt at the new face, the winding number's decides
    (`BodySurface.winding_sign`), as in a query. A caller that follows the planes of one cloth
    at many steps keeps a `PlaneFollower`, whose launch is recorded once.
    """
    follower = PlaneFollower(faces, x.shape[0], bodies, vert_body, band=band, min_move=min_move, stiffness=stiffness,
                             margin=margin, device=x.device)
    follower.hold(closest, normal, face, found_at)
    change = follower(x)
    return FollowedPlanes(follower.closest.clone(), follower.normal.clone(), follower.face.to(torch.int64),
                          follower.found_at.clone(), change.clone())


class PlaneFollower:
    """`follow_planes` for the samples of one cloth's faces on one set of bodies, called at many
    steps: it holds the planes (`hold`) and each call moves the followed samples' planes in place,
    with a launch recorded once on its own buffers, so a call costs the kernel and a copy of the
    positions, not the packing of its thirty arguments nor copies of the planes.

    Args:
        faces: the cloth's faces (F, 3); num_verts: V.
        bodies, vert_body, band, min_move, stiffness, margin, as `follow_planes`.

    Attributes:
        closest, normal, face, found_at: the held planes, (V + F, ...) each: closest points and
            unit normals (float64), body faces (int32), where each sample was when its plane was
            found (float64); updated in place by each call.
    """

    def __init__(self, faces: Tensor, num_verts: int, bodies: BodySurface, vert_body: Tensor | None, *, band: float,
                 min_move: float, stiffness: float, margin: float, device: torch.device) -> None:
        self.faces, self.bodies, self.stiffness, self.margin = faces, bodies, float(stiffness), float(margin)
        num_samples = num_verts + faces.shape[0]
        self.body = (torch.zeros(num_samples, dtype=torch.int32, device=device) if vert_body is None
                     else sample_index(vert_body, faces).to(torch.int32).contiguous())

        def vec3() -> Tensor:
            return torch.zeros(num_samples, 3, dtype=torch.float64, device=device)

        def scalar(dtype: torch.dtype) -> Tensor:
            return torch.zeros(num_samples, dtype=dtype, device=device)

        self._x = torch.zeros(1, num_verts, 3, dtype=torch.float64, device=device)
        self.closest, self.normal, self.face, self.found_at = vec3(), vec3(), scalar(torch.int32), vec3()
        self._before, self._change, self._followed = scalar(torch.float64), scalar(torch.float64), scalar(torch.int32)
        # the samples whose sign is in doubt, flagged by the kernel: at the bodies' doubtful faces
        # where found already (the flags hold while those are the bodies' doubtful faces), at every
        # followed sample before, none with the pseudo-normal sign alone
        self._doubtful = bodies.found_doubtful_faces()
        doubt_mode = 1 if self._doubtful is not None else (2 if bodies.sign_method is SignMethod.WINDING_NUMBER else 0)
        doubtful = (torch.zeros(1, 1, dtype=torch.int32, device=device) if self._doubtful is None
                    else self._doubtful.to(device=device, dtype=torch.int32).contiguous())
        self._launch = None
        if num_samples:
            wp = warp()
            vec, f64, i32 = wp.vec3d, wp.float64, wp.int32
            with torch_stream(device):
                self._launch = wp.launch(
                    contact_kernels.kernels()["follow"], dim=num_samples, device=wp.device_from_torch(device),
                    inputs=[launch_arg(self._x, vec), launch_arg(sample_corners(faces, num_verts), i32),
                            launch_arg(self.closest, vec), launch_arg(self.normal, vec), launch_arg(self.face, i32),
                            launch_arg(self.found_at, vec), launch_arg(self.body, i32), float(band), float(min_move),
                            self.stiffness, self.margin, *bodies.walk_arrays().launch_args(wp, WALK_MOVES),
                            launch_arg(doubtful, i32), doubt_mode],
                    outputs=[launch_arg(t, kind) for t, kind in
                             zip((self._before, self._change, self._followed), (f64, f64, i32))],
                    record_cmd=True)

    @torch.no_grad()
    def hold(self, closest: Tensor, normal: Tensor, face: Tensor, found_at: Tensor) -> None:
        """Hold these planes (closest points, normals, faces and where each sample was when its
        plane was found, (V + F, ...) each; a full query's)."""
        for held, given in zip((self.closest, self.normal, self.face, self.found_at),
                               (closest, normal, face, found_at)):
            held.copy_(given.detach())

    @torch.no_grad()
    def __call__(self, x: Tensor, *, bound: DistanceBound | None = None) -> Tensor:
        """`follow_planes` of positions x (V, 3) [m] from the held planes, which it updates;
        bound: an exact query's bound of the samples, which decides the side of those in doubt
        that cannot have crossed the body's surface since (`BodySurface.winding_sign`). Returns
        the change of each sample's penalty (V + F,) [J] float64 (0 where the plane was kept),
        valid until the next call."""
        if tuple(x.shape) != tuple(self._x.shape[1:]):
            raise ValueError(f"x must be the cloth's positions {tuple(self._x.shape[1:])}, got {tuple(x.shape)}")
        self._x[0].copy_(x.detach())
        if self._launch is not None:
            with torch_stream(x.device):
                self._launch.launch()
        change, followed = self._change, self._followed
        flagged = self._doubtful is None or self.bodies.found_doubtful_faces() is self._doubtful
        rows = torch.nonzero(followed >= 8 if flagged else followed)[:, 0]
        if rows.numel():  # the winding number's sign where it is in doubt, as a query takes it
            flags = followed[rows]
            x64 = self._x[0]

            def points32(doubt: Tensor) -> Tensor:
                return samples_at(x64, self.faces, rows[doubt]).to(torch.float32)

            def known(doubt: Tensor) -> Tensor:
                return bound.select(rows[doubt]).sign(samples_at(x64, self.faces, rows[doubt]))

            sign = self.bodies.winding_sign(points32, self.body[rows], self.face[rows].to(torch.int64),
                                            (flags & 2).bool(), (flags & 4).bool(),
                                            known=None if bound is None else known)
            if sign is not None:
                flipped = rows[sign[0][sign[2] < 0]]
                if flipped.numel():
                    self.normal[flipped] = -self.normal[flipped]
                    points = samples_at(x64, self.faces, flipped)
                    after = ((points - self.closest[flipped]) * self.normal[flipped]).sum(-1)
                    energy = partial(contact_energy, stiffness=self.stiffness, margin=self.margin)
                    change[flipped] = energy(after) - energy(self._before[flipped])
        return change


def contact_depth(distance: Tensor, *, margin: float) -> Tensor:
    """ReLU(ε − d) [m] per sample, distance d (S,) [m] → (S,)."""
    return (margin - distance).clamp_min(0.0)


def contact_energy(distance: Tensor, *, stiffness: float, margin: float) -> Tensor:
    """Penalty k_c ReLU(ε − d)³ [J] per sample, distance d (S,) [m] → (S,)."""
    return stiffness * contact_depth(distance, margin=margin) ** 3


def garment_energy(per_sample: Tensor, cloth: Cloth) -> Tensor:
    """Per-sample values (V + F,) summed per garment (G,): vertices by `vert_garment`, centroids by
    `face_garment`."""
    num_verts = cloth.num_verts
    return (cloth.sum_per_garment(per_sample[:num_verts], cloth.vert_garment)
            + cloth.sum_per_garment(per_sample[num_verts:], cloth.face_garment))


def to_vertices(per_sample: Tensor, faces: Tensor) -> Tensor:
    """Sum per-sample values (V + F, ...) onto the vertices (V, ...), a centroid's 1/3 to each corner."""
    num_verts = per_sample.shape[0] - faces.shape[0]
    corner = (per_sample[num_verts:] / 3.0).repeat_interleave(3, dim=0)
    return per_sample[:num_verts].index_add(0, faces.reshape(-1), corner)


def sample_corners(faces: Tensor, num_verts: int) -> Tensor:
    """The contact samples' corner table (V + F, 3) int32 on faces' device: a vertex sample's
    vertex three times, then each face's corners (`physics.contact_kernels`); made once per faces
    tensor and reused while it lives unmodified."""
    table = _CORNERS.get(faces, lambda f: _corner_table(f, num_verts))
    return table if table.shape[0] == num_verts + faces.shape[0] else _corner_table(faces, num_verts)


def _corner_table(faces: Tensor, num_verts: int) -> Tensor:
    verts = torch.arange(num_verts, dtype=torch.int32, device=faces.device)[:, None].expand(-1, 3)
    return torch.cat([verts, faces.to(torch.int32)]).contiguous()


#: Corner tables per faces tensor: a solver evaluates the contact of one cloth dozens of times.
_CORNERS = TensorMemo(64)


def plane_distance(x: Tensor, faces: Tensor, closest: Tensor, normal: Tensor) -> Tensor:
    """d = (s − p)·n [m] of every sample s of positions x (V, 3) [m] on its held plane: closest
    point p and unit normal n per sample (V + F, 3). Differentiable once in x; (V + F,) in x's dtype."""
    return _launch("distance", x, faces, closest, normal, None)


def plane_contact_forces(x: Tensor, faces: Tensor, closest: Tensor, normal: Tensor, *, stiffness: float,
                         margin: float) -> Tensor:
    """f = −∇_x E_c onto the vertices [N], (V, 3), with every sample's distance taken on its held
    plane (closest point p and unit normal n per sample, (V + F, 3)): 3 k_c ReLU(ε − d)² n per
    vertex sample, and a centroid's 3 k_c ReLU(ε − d)² n shared equally by its corners. With planes
    from a body query at x this is −∇ of the queried energy (∇d = n there). Differentiable once
    in x (the backward is the Gauss–Newton Hessian–vector product on the held planes)."""
    return _launch("force", x, faces, closest, normal, (3,), float(stiffness), float(margin))


def plane_contact_blocks(x: Tensor, faces: Tensor, closest: Tensor, normal: Tensor, *, stiffness: float,
                         margin: float, band: float = 0.0) -> Tensor:
    """The 3 × 3 diagonal blocks (V, 3, 3) [N/m] of E_c's Gauss–Newton Hessian on held planes: a
    vertex's own 6 k_c ReLU(ε − d) n nᵀ plus 1/9 of each of its faces' centroid blocks (the exact
    Hessian's diagonal blocks on the planes). Samples closer to their plane than `band` [m] are
    taken at depth ReLU(ε − min(d, 0)) ≥ ε instead (a preconditioner's choice, see
    `model.stretching_solver`). Not differentiated."""
    with torch.no_grad():
        return _launch("blocks", x.detach(), faces, closest, normal, (3, 3), float(stiffness), float(margin),
                       float(band))


def _launch(name: str, x: Tensor, faces: Tensor, closest: Tensor, normal: Tensor, out_dims: tuple | None,
            *scalars: float) -> Tensor:
    num_verts, num_samples = x.shape[-2], x.shape[-2] + faces.shape[0]
    if closest.shape != (num_samples, 3) or normal.shape != (num_samples, 3):
        raise ValueError(f"closest and normal must have shape ({num_samples}, 3) (the V + F samples), got "
                         f"{tuple(closest.shape)} and {tuple(normal.shape)}")
    return run_kernel(contact_kernels.kernels()[name], x, [sample_corners(faces, num_verts), closest, normal],
                      [0, 1, 1], num_samples, out_dims, scalars)


def contact_hessian_blocks(distance: Tensor, normal: Tensor, faces: Tensor, *, stiffness: float,
                           margin: float) -> tuple[Tensor, Tensor]:
    """Gauss–Newton blocks of E_c (closest points held fixed): per vertex (V, 3, 3)
    6 k_c ReLU(ε − d) n nᵀ from its own sample, and per face (F, 9, 9) the centroid's
    6 k_c ReLU(ε − d) n nᵀ / 9 in each of its 3 × 3 corner pairs. Their assembled sum is the
    Hessian in x of E_c on fixed planes.

    distance: d of every sample (V + F,) [m]; normal: unit outward body normal n at each sample's
    closest point (V + F, 3); faces: (F, 3).
    """
    num_verts = distance.shape[0] - faces.shape[0]
    depth = contact_depth(distance, margin=margin)
    nv, nc = normal[:num_verts], normal[num_verts:]
    vertex = (6.0 * stiffness * depth[:num_verts])[:, None, None] * nv[:, :, None] * nv[:, None, :]
    centroid = (6.0 * stiffness * depth[num_verts:] / 9.0)[:, None, None] * nc[:, :, None] * nc[:, None, :]
    face = centroid[:, None, :, None, :].expand(-1, 3, -1, 3, -1).reshape(-1, 9, 9)
    return vertex, face


def contact_vertices(distance: Tensor, faces: Tensor, *, margin: float) -> Tensor:
    """Vertices the contact acts on (V,) bool: within the margin themselves, or a corner of a face
    whose centroid is. distance: d of every sample (V + F,) [m]."""
    num_verts = distance.shape[0] - faces.shape[0]
    depth = contact_depth(distance, margin=margin)
    contact = depth[:num_verts] > 0
    contact[faces[depth[num_verts:] > 0].reshape(-1)] = True
    return contact


def penalty_contact_energy(x: Tensor, cloth: Cloth, bodies: BodySurface, vert_body: Tensor, *,
                           stiffness: float = DEFAULT_STIFFNESS, margin: float = DEFAULT_MARGIN) -> Tensor:
    """E_c per garment [J] (G,) at positions x (ΣV, 3) [m], from a body query of the vertices and
    face centroids; vert_body: body of each vertex (ΣV,). Differentiable in x.

    The centroids whose corners put them at least ε from the body are not searched
    (`query_samples_near` with reach ε): their penalty and its gradient are exactly 0 at their
    lower bound as at their distance, so E_c and its gradient are those of the query of every
    sample to the bit, with fewer searches where the garment stands off the body."""
    distance = query_samples_near(x, cloth.faces, bodies, vert_body, reach=margin).signed_distance.to(x.dtype)
    return garment_energy(contact_energy(distance, stiffness=stiffness, margin=margin), cloth)
