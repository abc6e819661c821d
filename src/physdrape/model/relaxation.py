"""What the two-level solver relaxes (`model.stretching_solver`): a garment batch's Φ on held
body planes, its force, its stiffness blocks and the body queries that renew the planes."""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.proximity import BodySurface, SurfaceQuery
from physdrape.physics.cloth import Cloth
from physdrape.physics.contact import (
    PlaneFollower,
    contact_samples,
    garment_energy,
    plane_contact_forces,
    query_samples,
)
from physdrape.physics.forces import extra_blocks, internal_forces, layer_link_weights, tie_forces
from physdrape.physics.layers import followed
from physdrape.physics.potential import GarmentPotential

__all__ = ["Relaxation"]


class Relaxation:
    """What the two-level solver relaxes: each garment's Φ = E_strain + E_bend + E_grav + E_c − f̂·x,
    with E_c the contact penalty of `physics.contact` at the vertices and face centroids on
    closest-point planes of the body, held between `requery` calls.

    The contact's Gauss-Newton blocks 6 k_c ReLU(ε − d) n nᵀ vanish at d ≥ ε, so a quadratic
    model of Φ does not see the body until the garment is in its margin; samples closer to their
    plane than `band` [m] get the blocks of depth ε instead (a preconditioner only: the line
    search still descends Φ). A vertex beyond the band that moved m in the last step gets that
    block too while it is within band + m of its plane, up to `reach` [m] (None: band): where
    the garment still moves far, a narrow band would let its steps run into the body (then
    `short_of_margin` stops them, and the stopped vertices hold their neighbours back). A local
    requery finds again the planes of the samples within `band` of theirs that moved more than
    `min_move` [m] since their planes were found. layer_slide: the layer pairs' tangential share β
    in the preconditioner's blocks (`physics.forces.extra_blocks`; None: the solver's own).
    active_links: each step keeps only the blocks of the layer pairs within
    `physics.forces.LAYER_LINK_REACH` of acting (`layer_link_weights`, in `link_weight` for the
    coarse space); else every link's block at every step.
    """

    def __init__(self, cloth: Cloth, f_hat: Tensor | None, *, margin: float, stiffness: float, band: float,
                 min_move: float = 0.0, reach: float | None = None, layer_slide: float | None = None,
                 active_links: bool = False) -> None:
        self.cloth, self.f_hat, self.margin, self.stiffness, self.band = cloth, f_hat, margin, stiffness, band
        self.min_move = min_move
        self.reach = band if reach is None else reach
        self._last_x: Tensor | None = None  # where the last step started (`step_terms`), float64
        self.planes: tuple[Tensor, Tensor] | None = None  # closest points and normals of the samples
        self._faces: Tensor | None = None  # the body triangle each sample's plane touches
        self._found_at: Tensor | None = None  # where each sample was when its plane was found
        self._follower: PlaneFollower | None = None  # the local requeries' recorded launch (made at the first)
        self._follower_holds = False  # whether the follower holds the current planes
        self.bound: DistanceBound | None = None  # the samples' distances at the last full query
        self._bound_bodies: BodySurface | None = None  # the bodies that query asked
        # formed once per solve, in the local terms' float64 (with `active_links`, again in place at every step)
        extra = extra_blocks(cloth, slide=layer_slide)
        self._extra = None if extra is None else extra.to(torch.float64)
        # the cloth the links were formed on (the template's layer pairs, whatever `follow_layers` adds)
        self._linked, self._layer_slide = cloth, layer_slide
        self._active_links = active_links and cloth.layers is not None
        self.link_weight: Tensor | None = None  # the links' weights at the last `step_terms`
        self._potential = GarmentPotential(cloth, external=f_hat, stiffness=stiffness, margin=margin, band=band)

    def drop_f_hat(self) -> None:
        """Relax without the −f̂·x term from now on, on the same held planes."""
        self.f_hat = None
        self._potential.drop_external()

    def requery(self, x: Tensor, bodies: BodySurface, body_index: Tensor | None, *,
                local: bool = False, query: SurfaceQuery | None = None) -> Tensor | None:
        """Query the body at the samples of x and hold the planes.

        local: only the samples within the contact band of their held planes (and, with
        `min_move`, moved that far since their planes were found); the others keep theirs (no
        contact term or block reaches them at this step: they are more than a band away from the
        body; or their planes are a fraction of a millimetre old). Returns the change of Φ at x
        per garment (G,) [J], float64, that the new planes make (only the followed samples'
        penalties change), or None after a full query (every plane may have changed: Φ is
        evaluated anew). query: x's samples' full query, made already (a `query_samples_near`
        stand-in's distance is a lower bound, which keeps the held bound valid).
        """
        with torch.no_grad():
            if not local or self.planes is None:
                q = query if query is not None else query_samples(x.detach(), self.cloth.faces, bodies, body_index,
                                                                  bound=self._bound_on(bodies))
                # float64, the contact kernels' dtype (converted once per requery, not per evaluation)
                self.planes = (q.closest.to(torch.float64).contiguous(), q.normal.to(torch.float64).contiguous())
                samples = contact_samples(x.detach().to(torch.float64), self.cloth.faces)
                self._faces, self._found_at, self._follower_holds = q.face, samples, False
                self.bound, self._bound_bodies = DistanceBound.of(samples, q.signed_distance), bodies
                change = None
            else:
                if self._follower is None or self._follower.bodies is not bodies:
                    self._follower = PlaneFollower(self.cloth.faces, self.cloth.num_verts, bodies, body_index,
                                                   band=self.band, min_move=self.min_move, stiffness=self.stiffness,
                                                   margin=self.margin, device=x.device)
                    self._follower_holds = False
                follower = self._follower
                if not self._follower_holds:
                    follower.hold(*self.planes, self._faces, self._found_at)
                    self._follower_holds = True
                change = garment_energy(follower(x, bound=self._bound_on(bodies)), self.cloth)
                # the follower's planes, moved in place at each call (copies where a differentiated
                # force may keep them for its backward)
                self.planes = ((follower.closest, follower.normal) if not x.requires_grad
                               else (follower.closest.clone(), follower.normal.clone()))
                self._faces, self._found_at = follower.face, follower.found_at
        self._potential.hold(self.planes)
        return change

    def follow_layers(self, x: Tensor) -> None:
        """Complete the layer order's template pairs by those found at x (`physics.layers.followed`)
        in Φ and the force from now on, as the oracle and the measured energy do; the
        preconditioner's blocks keep the template's pairs (its structure is built once). No-op
        for a layer order that does not follow."""
        layers = self.cloth.layers
        if layers is None or not layers.follows:
            return
        with torch.no_grad():
            self.cloth = replace(self.cloth, layers=followed(layers, x.detach()))
        self._potential.hold_layers(self.cloth.layers)

    def _bound_on(self, bodies: BodySurface) -> DistanceBound | None:
        """The last full query's bound where it was of these bodies (it decides the side of the
        samples in doubt that cannot have crossed their surface since), else None."""
        return self.bound if bodies is self._bound_bodies else None

    def _vertex_planes(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """The vertices' signed distances to their held planes (V,) [m] and the planes' normals
        (V, 3), in x's dtype; x (V, 3)."""
        closest, normal = (plane[:x.shape[0]].to(x.dtype) for plane in self.planes)
        return ((x - closest) * normal).sum(-1), normal

    def _vertex_bands(self, x: Tensor) -> Tensor | None:
        """The band of each vertex's own contact sample (V,) [m], float64: the band plus the
        vertex's move since the last call, up to `reach` (None: the band alone: no reach beyond
        it, the first call, or no planes); x (V, 3) float64 becomes the last call's positions."""
        if self.reach <= self.band:
            return None
        last, self._last_x = self._last_x, x.clone()
        if last is None or self.planes is None:
            return None
        return (self.band + (x - last).norm(dim=-1)).clamp(max=self.reach)

    def short_of_margin(self, move: Tensor, x: Tensor) -> Tensor:
        """The step `move` (V, 3) [m] from x with each vertex's move scaled down, where it would
        carry the vertex from beyond the band into the margin of its held plane, to the move that
        ends at the margin (no planes: the move as it is).

        Beyond the band the preconditioner has no contact block for a vertex (`local_terms`), so a
        step that is still long (X_init's strain relaxing) can aim it through the body; the line
        search's one length per garment then shortens every vertex's step for those few, and the
        garment stalls. Vertices within the band keep their moves: their blocks hold them, and
        the garment has to settle onto the body there. The scale is held constant in the gradient."""
        if self.planes is None:
            return move
        with torch.no_grad():
            distance, normal = self._vertex_planes(x.detach())
            inward = -(move.detach() * normal).sum(-1)
            room = (distance - self.margin).clamp_min(0.0)
            limited = (distance >= self.band) & (inward > room)
            scale = torch.where(limited, room / inward.clamp_min(torch.finfo(x.dtype).tiny), torch.ones_like(room))
        return move * scale[:, None]

    def potential(self, x: Tensor) -> Tensor:
        """Φ per garment (G,) [J], float64 (`physics.potential`: one launch), on the held planes."""
        return self._potential(x)

    def force(self, x: Tensor) -> Tensor:
        """−∇Φ (V, 3) [N]."""
        force = internal_forces(x, self.cloth)
        if self.planes is not None:
            force = force + plane_contact_forces(x, self.cloth.faces, *self.planes, stiffness=self.stiffness,
                                                 margin=self.margin)
        if self.f_hat is not None:
            force = force + self.f_hat
        return force

    def step_terms(self, x: Tensor, *, pairs: tuple[Tensor, int] | None = None
                   ) -> tuple[Tensor, Tensor | None, Tensor, Tensor | None]:
        """What a step starts from at x, in x's dtype, from one launch (`GarmentPotential.local_terms`):

        - the force −∇Φ (V, 3) [N]; where x or f̂ carries a gradient (training), the force of
          `force`, differentiable through the same per-element formulas;
        - the contact's per-vertex Gauss-Newton blocks (V, 3, 3) [N/m] on the held planes, samples
          within `band` of their plane (vertices that moved since the last call: within band +
          their move, up to `reach`) taken at depth ≥ ε, plus the grip's and the diagonal blocks
          of the stitches' and layer pairs' (`physics.forces.extra_blocks`; the coarse space adds
          their coupling); or None without any;
        - the inverses of the per-vertex stiffness blocks K_i (strain, bending, contact) (V, 3, 3)
          [m/N], each floored relative to its own stiffness (`physics.majorant.compliance`): each
          vertex gets the compliance of its own stiffness;
        - with `pairs` (a coarse space's `pair_layout`), the strain majorant's pair blocks
          (P, 3, 3) float64 from the same launch, for the coarse factorisation (valid until the
          next call); else None.
        """
        bands = self._vertex_bands(x.detach().to(torch.float64))
        if self._active_links:  # in place: the recorded launches read this buffer
            self.link_weight = layer_link_weights(self._linked, x.detach())
            self._extra.copy_(extra_blocks(self._linked, slide=self._layer_slide, weight=self.link_weight))
        terms = self._potential.local_terms(x, extra=self._extra, vertex_band=bands,
                                            rel=max(1e-6, 100.0 * torch.finfo(x.dtype).eps),
                                            tiny=float(torch.finfo(x.dtype).tiny), pairs=pairs)
        if torch.is_grad_enabled() and (x.requires_grad or (self.f_hat is not None and self.f_hat.requires_grad)):
            force = self.force(x)
        else:
            force = terms.force.to(x.dtype, copy=True)  # the terms are the potential's buffers: copied out
            ties = tie_forces(x.detach(), self.cloth)
            force = force if ties is None else force + ties
        contact = None if self.planes is None and self._extra is None else terms.contact.to(x.dtype, copy=True)
        return force, contact, terms.compliance.to(x.dtype, copy=True), terms.pairs
