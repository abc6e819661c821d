"""Each garment's total potential on held body planes, in one Warp launch: what the stretching
solver's line search evaluates two or three times per step; and, in one more launch, the force
and the stiffness blocks that the solver's step starts from (`GarmentPotential.local_terms`).

    Φ_g = E_strain + E_bend + E_grav + E_c − f_ext·x (+ E_grip + E_stitch + E_layer)

summed over the elements of garment g, with E_c the body-contact penalty of `physics.contact` on
held closest-point planes and f_ext a constant external force per vertex (the solver's f̂).

The terms' per-element formulas are the element kernels' (`physics.element_kernels`: the StVK
energy of a face, the bending energy of a hinge) and the contact kernels' (`physics.contact_kernels`:
a sample's distance to its held plane and its penalty); this module adds only their sum per
garment, in one launch with one thread per face (its strain and its centroid's contact), per hinge
(its bending) and per vertex (its gravity, its contact and the external force's work), each adding
its share into its garment's total. Composed from the per-element launches, with per-element
outputs that torch sums per garment, the same Φ costs more in per-op overhead than in
arithmetic on the CPU. The terms that tie vertices beyond
the elements (grip, stitches, layers) are added by their torch functions (`forces.tie_energy_terms`).

The force and blocks come from the majorant's local-terms kernel (`physics.majorant`), which
shares a face's deformation and stress, and a hinge's angle gradients, between the force and the
blocks; the held planes and the external force are this module's, as for Φ.

Not differentiated (a line search compares values; the solver's training differentiates the
force of `physics.forces.internal_forces` and `contact.plane_contact_forces`, the same per-element
formulas); computed in float64 whatever x's dtype. On a
CPU with several torch threads a packed batch's launch is split between its garments, whose totals
are disjoint (`physdrape.threads`).
"""

# No `from __future__ import annotations` here: Warp reads the kernels' annotations as objects.
from dataclasses import replace

import torch
from torch import Tensor

from physdrape.physics import contact_kernels, element_kernels
from physdrape.physics.cloth import Cloth
from physdrape.physics.contact import sample_corners
from physdrape.physics.forces import tie_energy_terms
from physdrape.physics.layers import LayerOrder
from physdrape.physics.majorant import (
    LocalTerms,
    record_compliance,
    record_local_terms,
    zero_local_terms,
)
from physdrape.tensor_memo import TensorMemo
from physdrape.threads import disjoint_parts, run_parts
from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["GarmentPotential"]


@defined_once
def _kernel():
    """Define the kernel (first call only; Warp caches the compiled code on disk)."""
    wp = warp()
    elements, contact = element_kernels._kernels(), contact_kernels.kernels()
    face_strain_energy, hinge_bend_energy = elements["face_strain_energy"], elements["hinge_bend_energy"]
    plane_distance, penalty = contact["plane_distance"], contact["penalty"]

    @wp.kernel(enable_backward=False)
    def potential_kernel(x: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                         rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                         mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64),
                         face_garment: wp.array(dtype=wp.int32), hinges: wp.array2d(dtype=wp.int32),
                         bend_stiffness: wp.array(dtype=wp.float64), hinge_garment: wp.array(dtype=wp.int32),
                         mass: wp.array(dtype=wp.float64), gravity: wp.array(dtype=wp.vec3d),
                         vert_garment: wp.array(dtype=wp.int32), external: wp.array(dtype=wp.vec3d),
                         with_external: int, corners: wp.array2d(dtype=wp.int32), closest: wp.array(dtype=wp.vec3d),
                         normal: wp.array(dtype=wp.vec3d), with_planes: int, stiffness: wp.float64,
                         margin: wp.float64, face_lo: int, num_faces: int, hinge_lo: int, num_hinges: int,
                         vert_lo: int, num_verts: int, out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        if i < num_faces:
            f = face_lo + i
            e = face_strain_energy(x, faces, rest_inv, volume, mu, lam, 0, f)
            if with_planes != 0:  # the face's centroid sample: V + f
                e = e + penalty(plane_distance(x, corners, closest, normal, 0, num_verts + f), stiffness, margin)
            wp.atomic_add(out, face_garment[f], e)
        elif i < num_faces + num_hinges:
            h = hinge_lo + i - num_faces
            wp.atomic_add(out, hinge_garment[h], hinge_bend_energy(x, hinges, bend_stiffness, 0, h))
        else:
            v = vert_lo + i - num_faces - num_hinges
            g = vert_garment[v]
            e = -mass[v] * wp.dot(gravity[g], x[0, v])
            if with_external != 0:
                e = e - wp.dot(external[v], x[0, v])
            if with_planes != 0:
                e = e + penalty(plane_distance(x, corners, closest, normal, 0, v), stiffness, margin)
            wp.atomic_add(out, g, e)

    return wp, potential_kernel


class GarmentPotential:
    """Φ per garment of one cloth (module docstring), evaluated at many positions.

    The launches are recorded once per set of planes (`hold`) and replayed: x is copied into a float64
    buffer the recorded launch reads and the totals are summed into a buffer it writes, so a call
    costs the kernel and a copy, not the packing of its two dozen arguments.

    Args:
        cloth: the packed garments.
        external: a constant force per vertex (V, 3) [N] whose work −f·x enters Φ, or None.
        stiffness, margin: k_c [J/m³] and ε [m] of the contact penalty on the held planes.
        band: the contact blocks' band [m] (`local_terms`).
    """

    def __init__(self, cloth: Cloth, *, external: Tensor | None = None, stiffness: float = 0.0,
                 margin: float = 0.0, band: float = 0.0) -> None:
        num_verts = cloth.num_verts
        if external is not None and tuple(external.shape) != (num_verts, 3):
            raise ValueError(f"external must be a force per vertex ({num_verts}, 3), got {tuple(external.shape)}")
        self.cloth, self.stiffness, self.margin, self.band = cloth, float(stiffness), float(margin), float(band)
        device = cloth.faces.device
        constant = element_kernels.kernel_constant
        self._x = torch.zeros(1, num_verts, 3, dtype=torch.float64, device=device)
        self._out = torch.zeros(cloth.num_garments, dtype=torch.float64, device=device)
        self._external = (None if external is None else  # its own copy (`drop_external` zeroes it)
                          external.detach().to(device=device, dtype=torch.float64, copy=True).contiguous())
        self._constants = [constant(t) for t in (cloth.faces, cloth.rest_inv, cloth.volume, cloth.mu, cloth.lam,
                                                 cloth.face_garment, cloth.hinges, cloth.bend_stiffness,
                                                 cloth.hinge_garment, cloth.mass, cloth.gravity, cloth.vert_garment)]
        self._corners = sample_corners(cloth.faces, num_verts)
        self._planes: tuple[Tensor, Tensor] | None = None
        self._terms = zero_local_terms(num_verts, device)  # the buffers `local_terms` sums into
        self._pair_terms: tuple[Tensor, LocalTerms] | None = None  # a pair layout and the same with its pairs
        self._inverse = torch.zeros(num_verts, 3, 3, dtype=torch.float64, device=device)  # and inverts into
        self._vertex_band: Tensor | None = None  # the vertices' own bands `local_terms` reads (made at first use)
        # recorded launches: Φ's per thread count, the local terms' per ("local", thread count, banded) and
        # with a pair layout's blocks per ("pairs", thread count, banded) (banded: with the vertices' own
        # bands), the compliance's per ("compliance", rel, tiny)
        self._launches: dict = {}

    def drop_external(self) -> None:
        """Evaluate Φ and the local terms without the external force's work from now on (its copy
        zeroed: the recorded launches stay valid)."""
        if self._external is not None:
            self._external.zero_()

    def hold_layers(self, layers: LayerOrder) -> None:
        """Evaluate the layer term with these pairs from now on (those a solver found where the
        pieces are, `physics.layers.followed`); the recorded launches do not read it."""
        self.cloth = replace(self.cloth, layers=layers)

    def hold(self, planes: tuple[Tensor, Tensor] | None) -> None:
        """Evaluate the contact on these planes from now on: the samples' closest points and unit
        normals (V + F, 3) each (`physics.contact`), or None (no contact term). The planes are
        copied into buffers of this potential's own, so that a solver moving them at every step
        replays the same recorded launch."""
        if planes is None:
            if self._planes is not None:
                self._launches = {}
            self._planes = None
            return
        samples = self.cloth.num_verts + self.cloth.faces.shape[0]
        if tuple(planes[0].shape) != (samples, 3) or tuple(planes[1].shape) != (samples, 3):
            raise ValueError(f"the planes must have shape ({samples}, 3) (the V + F samples), "
                             f"got {tuple(planes[0].shape)} and {tuple(planes[1].shape)}")
        if self._planes is None:  # the first planes: the buffers, and the launches recorded on them
            self._planes = tuple(torch.empty(samples, 3, dtype=torch.float64, device=self._x.device) for _ in range(2))
            self._launches = {}
        for held, plane in zip(self._planes, planes):
            held.copy_(plane.detach())

    def local_terms(self, x: Tensor, *, extra: Tensor | None = None, rel: float | None = None,
                    tiny: float = 0.0, pairs: tuple[Tensor, int] | None = None,
                    vertex_band: Tensor | None = None) -> LocalTerms:
        """The force −∇Φ and the stiffness blocks at positions x (V, 3) [m] on the held planes, in
        one launch (`physics.majorant.LocalTerms`, float64): the force of the strain, bending,
        gravity, external and contact terms (the ties' are the caller's: `forces.tie_forces`),
        the majorant's vertex blocks and the contact's blocks, samples within `band` of their
        plane taken at depth ≥ ε (`contact.plane_contact_blocks`; with `vertex_band` (V,) [m], a
        vertex's own sample within its entry instead), plus `extra` (V, 3, 3) [N/m] if given;
        with `rel`, also the inverses of the vertices' blocks and contact blocks, floored by rel
        and tiny (`physics.majorant.compliance`), in a second launch; with `pairs`, the pair layout
        (pair_of_corner (F, 9) int32, number of pairs) of `physics.majorant.pair_blocks`, also the
        strain majorant's pair blocks, from the same faces' state. Not differentiated.
        The terms are this potential's buffers, valid until its next `local_terms` call."""
        if tuple(x.shape) != (self.cloth.num_verts, 3):
            raise ValueError(f"x must be the cloth's packed positions ({self.cloth.num_verts}, 3), got {tuple(x.shape)}")
        threads = torch.get_num_threads() if x.device.type == "cpu" else 1
        terms = self._terms
        if pairs is not None:
            if self._pair_terms is None or self._pair_terms[0] is not pairs[0]:  # a layout's buffer and launches
                self._pair_terms = (pairs[0], replace(terms, pairs=torch.zeros(pairs[1], 3, 3, dtype=torch.float64,
                                                                               device=x.device)))
                self._launches = {k: v for k, v in self._launches.items()
                                  if not (isinstance(k, tuple) and k[0] == "pairs")}
            terms = self._pair_terms[1]
        with torch.no_grad():
            self._x[0].copy_(x.detach())
            for buffer in (terms.force, terms.blocks, terms.contact) + (() if pairs is None else (terms.pairs,)):
                buffer.zero_()
            if vertex_band is not None:
                if self._vertex_band is None:
                    self._vertex_band = torch.zeros(self.cloth.num_verts, dtype=torch.float64, device=x.device)
                self._vertex_band.copy_(vertex_band.detach())
            with torch_stream(x.device):
                key = ("local" if pairs is None else "pairs", threads, vertex_band is not None)
                launches = self._launches.get(key)
                if launches is None:
                    launches = self._launches[key] = [
                        record_local_terms(self._x, self.cloth, terms, part, external=self._external,
                                           corners=self._corners, planes=self._planes, stiffness=self.stiffness,
                                           margin=self.margin, band=self.band,
                                           pair_of_corner=None if pairs is None else pairs[0],
                                           vertex_band=None if vertex_band is None else self._vertex_band)
                        for part in _garment_parts(self.cloth, threads)]
                run_parts(lambda k: launches[k].launch(), [(k,) for k in range(len(launches)) if launches[k]],
                          "elements")
                if extra is not None:
                    terms.contact.add_(extra.detach())
                inverse = None
                if rel is not None:
                    key = ("compliance", float(rel), float(tiny))
                    if key not in self._launches:
                        self._launches[key] = record_compliance(terms.blocks, terms.contact, self._inverse, rel=rel,
                                                                tiny=tiny)
                    if self._launches[key] is not None:
                        self._launches[key].launch()
                    inverse = self._inverse
            return LocalTerms(terms.force, terms.blocks, terms.contact, inverse, terms.pairs)

    def __call__(self, x: Tensor) -> Tensor:
        """Φ per garment (G,) [J], float64, at positions x (V, 3) [m]; not differentiated."""
        if tuple(x.shape) != (self.cloth.num_verts, 3):
            raise ValueError(f"x must be the cloth's packed positions ({self.cloth.num_verts}, 3), got {tuple(x.shape)}")
        threads = torch.get_num_threads() if x.device.type == "cpu" else 1
        with torch.no_grad():
            self._x[0].copy_(x.detach())
            self._out.zero_()
            with torch_stream(x.device):
                launches = self._launches.get(threads)
                if launches is None:
                    launches = self._launches[threads] = [self._record(part)
                                                          for part in _garment_parts(self.cloth, threads)]
                run_parts(lambda k: launches[k].launch(), [(k,) for k in range(len(launches)) if launches[k]],
                          "elements")
            out = self._out.clone()
            ties = tie_energy_terms(self._x[0], self.cloth)
            return out + sum(ties.values()) if ties else out

    def _record(self, part: tuple[int, ...]):
        """The launch over one part's faces, hinges and vertices, recorded (None: an empty part)."""
        wp, kernel = _kernel()
        face_lo, face_hi, hinge_lo, hinge_hi, vert_lo, vert_hi = part
        dim = (face_hi - face_lo) + (hinge_hi - hinge_lo) + (vert_hi - vert_lo)
        if not dim:
            return None
        idle = _placeholder(self._x.device)
        closest, normal = self._planes if self._planes is not None else (idle, idle)
        corners = self._corners if self._planes is not None else _placeholder(self._x.device, torch.int32)
        external = self._external if self._external is not None else idle
        (faces, rest_inv, volume, mu, lam, face_garment, hinges, bend_stiffness, hinge_garment, mass, gravity,
         vert_garment) = self._constants
        inputs = [launch_arg(self._x, wp.vec3d), launch_arg(faces, wp.int32), launch_arg(rest_inv, wp.mat22d),
                  launch_arg(volume, wp.float64), launch_arg(mu, wp.float64), launch_arg(lam, wp.float64),
                  launch_arg(face_garment, wp.int32), launch_arg(hinges, wp.int32),
                  launch_arg(bend_stiffness, wp.float64), launch_arg(hinge_garment, wp.int32),
                  launch_arg(mass, wp.float64), launch_arg(gravity, wp.vec3d), launch_arg(vert_garment, wp.int32),
                  launch_arg(external, wp.vec3d), int(self._external is not None), launch_arg(corners, wp.int32),
                  launch_arg(closest, wp.vec3d), launch_arg(normal, wp.vec3d), int(self._planes is not None),
                  self.stiffness, self.margin, face_lo, face_hi - face_lo, hinge_lo, hinge_hi - hinge_lo, vert_lo,
                  self.cloth.num_verts]
        return wp.launch(kernel, dim=dim, device=wp.device_from_torch(self._x.device), inputs=inputs,
                         outputs=[launch_arg(self._out, wp.float64)], record_cmd=True)


def _garment_parts(cloth: Cloth, threads: int) -> list[tuple[int, int, int, int, int, int]]:
    """(face lo, hi, hinge lo, hi, vertex lo, hi) ranges, one per part, each covering whole
    garments: the faces split as `disjoint_parts` splits them, each part's hinges and vertices those
    of its garments (a packed batch lists each garment's elements together, in garment order)."""
    whole = [(0, cloth.faces.shape[0], 0, cloth.hinges.shape[0], 0, cloth.num_verts)]
    face_parts = disjoint_parts(cloth.faces, threads) if threads > 1 else [(0, cloth.faces.shape[0])]
    if len(face_parts) < 2:
        return whole
    known = _PARTS.get(cloth.faces, lambda _: {})
    key = tuple(face_parts)
    if key not in known:
        known[key] = _split_by_garment(cloth, face_parts)
    return known[key]


def _split_by_garment(cloth: Cloth, face_parts: list[tuple[int, int]]) -> list[tuple[int, int, int, int, int, int]]:
    owners = (cloth.face_garment, cloth.hinge_garment, cloth.vert_garment)
    if any(bool((o[1:] < o[:-1]).any()) for o in owners):  # not packed garment after garment: one part
        return [(0, cloth.faces.shape[0], 0, cloth.hinges.shape[0], 0, cloth.num_verts)]
    bounds = [int(cloth.face_garment[lo]) for lo, _ in face_parts] + [cloth.num_garments]
    edges = torch.tensor(bounds, dtype=cloth.face_garment.dtype, device=cloth.face_garment.device)
    ranges = [torch.searchsorted(o, edges).tolist() for o in owners]
    return [tuple(r[k + j] for r in ranges for j in (0, 1)) for k in range(len(face_parts))]


#: Per-garment launch parts per faces tensor (`_garment_parts`).
_PARTS = TensorMemo(64)
#: One-row stand-ins for the arrays of an absent term, per (device, dtype).
_PLACEHOLDERS: dict = {}


def _placeholder(device: torch.device, dtype: torch.dtype = torch.float64) -> Tensor:
    key = (str(device), dtype)
    if key not in _PLACEHOLDERS:
        _PLACEHOLDERS[key] = torch.zeros(1, 3, dtype=dtype, device=device)
    return _PLACEHOLDERS[key]
