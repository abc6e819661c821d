"""The learnable stretching solver (paper Eq. 10) on the analytic internal forces."""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from functools import partial

import torch
from torch import Tensor, nn

from physdrape.geometry.proximity import BodySurface, SurfaceQuery
from physdrape.model.relaxation import Relaxation
from physdrape.physics.cloth import Cloth
from physdrape.physics.coarse_space import CoarseSpace
from physdrape.physics.forces import internal_forces
from physdrape.threads import one_blas_thread


class SolverKind(str, enum.Enum):
    """How the solver turns forces into steps (see `StretchingSolver`)."""

    EXPLICIT = "explicit"  # the paper's Eq. 10 as written: a scalar compliance η [m/N]
    TWO_LEVEL = "two_level"  # preconditioned conjugate directions with body contact and a line search


class StretchingSolver(nn.Module):
    """X^{t+1} = X^t + η γ^t C_t (F(X^t) + f̂), t = 0 … T−1.

    f̂ is the GNN's estimate of the forces the explicit model lacks (body support, contact,
    unresolved stress; DESIGN.md Sec. 3.5), held fixed over the first `f_hat_steps` steps (all T
    by default), so those steps relax toward F = −f̂ and the later ones toward F = 0. η > 0 is
    exp-parametrised, γ ∈ (0, 1) sigmoid-parametrised.

    - ``kind="explicit"`` (the paper's Eq. 10, the baseline): C = I, F = F_int, η a compliance
      in m/N.
    - ``kind="two_level"``: each garment's Φ = E_strain + E_bend + E_grav + E_c − f̂·x (plus the
      cloth's grip, stitch and layer-order terms; at each full body query a multi-piece garment's
      layer pairs are completed where its pieces are, `Relaxation.follow_layers`, as the oracle
      and the measured energy complete them), with E_c
      the body-contact penalty of `physics.contact` (the training loss's and the oracle's term:
      vertices and face centroids) on closest-point planes of the body, queried every
      `requery_every` steps (and with `follow_planes` walked to again at the steps between where
      the garment is near the body) so that gravity cannot pull the garment through the body mid-solve,
      minimised by preconditioned nonlinear conjugate gradients (Polak-Ribière+, restarted where
      the direction does not descend). η is dimensionless (1 = a full preconditioned step). The
      preconditioner is two-level: C = K⁻¹ + P (Pᵀ K P)⁻¹ Pᵀ, K⁻¹ block Jacobi (K_i the 3×3
      diagonal block of a PSD majorant of the Hessian of E_strain + E_bend + E_c,
      `physics.majorant.compliance`: each vertex gets the compliance of its own stiffness, so
      one η suits small and large faces, soft and stiff fabrics), the second term the Galerkin
      correction on a garment's smooth patches (`physics.coarse_space.CoarseSpace`), which moves
      what block Jacobi cannot: the garment sliding, riding up or stretching as a whole. The body
      planes are refreshed every `requery_every` steps, the coarse factor every `refactor_every`
      steps: Pᵀ K P at a garment still stretched from X_init is far stiffer than after a step
      that relaxed it, so a stale factor shortens the coarse moves. Each step's length is
      the minimum of a parabola through Φ along the clipped move η γ^t C F (then halved while Φ
      does not drop), so no step raises a garment's Φ (on the planes held at that step). C, the
      conjugation and the step length are not differentiated; the step is, through F, f̂, η, γ.
      At the first `inner_steps` steps the direction can be a truncated Newton step instead:
      `inner_iterations` iterations of conjugate gradients on the quadratic model K z = F from
      z = 0, preconditioned by C (one iteration: C F itself), K the PSD majorant that the coarse
      space factorises (`CoarseSpace.stiffness_product`: strain, contact and the links; bending
      only through C). A few iterations reach what one application of C leaves: the coupling
      between neighbouring vertices and patches, largest while X_init's strain relaxes; more
      converge on the majorant's minimum, which overshoots Φ's (the line search then shortens
      them). The iterations' coefficients are not differentiated (z stays linear in F).

    Stability guard (both kinds): each vertex's step is clipped to `max_step` [m] in length,
    keeping its direction. Kinematic initialisations can stretch edges where the pose pulls the
    skin (armpits, shoulders); StVK forces there reach thousands of times a vertex's weight, and
    an unclipped explicit step would diverge.

    Args:
        kind: `SolverKind`.
        eta: initial η ([m/N] explicit; dimensionless two_level, 1 = a full preconditioned step).
        gamma: initial decay γ.
        max_step: longest move of one vertex in one step [m] (0 disables the guard).
        margin, contact_stiffness: ε [m] and k_c [J/m³] of the two-level solver's contact term.
        requery_every: two-level steps between body queries (the planes are held in between).
        refactor_every: two-level steps between factorisations of the coarse space at the current
            positions (the factor is held in between); None: with the body planes.
        refactor_first: the first steps that factorise the coarse space at every step (then every
            `refactor_every`): the garment's stiffness changes most while X_init's strain relaxes.
        follow_planes: at the steps between body queries, find the closest body faces again
            for the samples within `contact_band` of their held planes, by a walk from their
            planes' faces over the faces around them (`physics.contact.follow_planes`, one launch;
            the others, out of the contact's reach at that step, keep theirs): the planes follow the garment
            where it touches the body at every step, for a fraction of a full query's cost; the
            full query every `requery_every` steps finds what a walk cannot reach (a closer
            sheet of the body farther along it).
        follow_min_move: with follow_planes, a sample's plane is found again only once the sample
            has moved more than this [m] since it was last found (0: at every step). A plane found
            a millimetre ago misses the body's surface there by about the move squared over the
            body's radius of curvature, micrometres, and late steps move most samples by less:
            they keep their planes, and the walks are spent where the garment still slides.
        f_hat_steps: the first steps that carry f̂ (None: every step). The later steps relax the
            garment's own energy, so that a long solve ends at the physics' equilibrium and not
            at F = −f̂: the network's force estimate guides the steps it was trained through.
        eval_requery_every, eval_follow_planes: requery_every and follow_planes in eval mode
            (`nn.Module.eval`: validation, evaluation, inference); None: as in training. The
            planes' schedule changes no weight, so a model can be trained on one schedule and
            drape with another (training through followed planes teaches the network moves the
            solver then takes back, `docs/training/README.md`).
        inner_steps, inner_iterations: the first steps whose direction is `inner_iterations`
            preconditioned conjugate-gradient iterations on K z = F (1: C F, no iteration).
        eval_inner_iterations: inner_iterations in eval mode (None: as in training).
        max_halvings: step halvings before a step that does not lower Φ is skipped.
        coarse_levels, coarse_smoothing: the two-level solver's patches (`CoarseSpace`).
        contact_band: the two-level solver's contact band [m]: samples closer to their body plane
            than this get the penalty's stiffness at depth ε in the preconditioner, and their
            planes are the ones followed (`Relaxation`). The first step that `step_parts` and
            `preconditioner` make is always made with it (a network reads them as trained).
        eval_contact_band: contact_band of the steps in eval mode (None: as in training).
    """

    def __init__(self, *, kind: SolverKind | str, eta: float, margin: float, contact_stiffness: float,
                 gamma: float = 0.9, max_step: float = 5e-3, requery_every: int = 5, refactor_every: int | None = None,
                 refactor_first: int = 0, follow_planes: bool = False, max_halvings: int = 6,
                 coarse_levels: int = 2, coarse_smoothing: int = 2, contact_band: float = 0.01,
                 eval_requery_every: int | None = None, eval_follow_planes: bool | None = None,
                 f_hat_steps: int | None = None, follow_min_move: float = 0.0, inner_steps: int = 0,
                 inner_iterations: int = 1, eval_inner_iterations: int | None = None,
                 eval_contact_band: float | None = None) -> None:
        super().__init__()
        if not eta > 0 or not 0 < gamma < 1:
            raise ValueError(f"need eta > 0 and 0 < gamma < 1, got eta={eta}, gamma={gamma}")
        if max_step < 0:
            raise ValueError(f"max_step must be ≥ 0 [m], got {max_step}")
        refactor_every = requery_every if refactor_every is None else refactor_every
        eval_requery_every = requery_every if eval_requery_every is None else eval_requery_every
        if min(requery_every, eval_requery_every, refactor_every) < 1 or refactor_first < 0 or max_halvings < 0:
            raise ValueError(f"need requery_every ≥ 1, eval_requery_every ≥ 1, refactor_every ≥ 1, refactor_first ≥ 0 "
                             f"and max_halvings ≥ 0, got {requery_every}, {eval_requery_every}, {refactor_every}, "
                             f"{refactor_first}, {max_halvings}")
        eval_inner_iterations = inner_iterations if eval_inner_iterations is None else eval_inner_iterations
        if inner_steps < 0 or min(inner_iterations, eval_inner_iterations) < 1:
            raise ValueError(f"need inner_steps ≥ 0, inner_iterations ≥ 1 and eval_inner_iterations ≥ 1, got "
                             f"{inner_steps}, {inner_iterations}, {eval_inner_iterations}")
        if f_hat_steps is not None and f_hat_steps < 0:
            raise ValueError(f"f_hat_steps must be ≥ 0 (None: every step), got {f_hat_steps}")
        eval_contact_band = contact_band if eval_contact_band is None else eval_contact_band
        if coarse_levels < 1 or coarse_smoothing < 0 or min(contact_band, eval_contact_band) < 0 or follow_min_move < 0:
            raise ValueError(f"need coarse_levels ≥ 1, coarse_smoothing ≥ 0, contact_band and eval_contact_band "
                             f"≥ 0 [m] and follow_min_move ≥ 0 [m], got {coarse_levels}, {coarse_smoothing}, "
                             f"{contact_band}, {eval_contact_band}, {follow_min_move}")
        self.kind = SolverKind(kind)
        self.max_step = max_step
        self.margin, self.contact_stiffness = margin, contact_stiffness
        self.requery_every, self.refactor_every, self.max_halvings = requery_every, refactor_every, max_halvings
        self.refactor_first = refactor_first
        self.follow_planes = follow_planes
        self.eval_requery_every = eval_requery_every
        self.eval_follow_planes = follow_planes if eval_follow_planes is None else eval_follow_planes
        self.f_hat_steps = f_hat_steps
        self.coarse_levels, self.coarse_smoothing = coarse_levels, coarse_smoothing
        self.contact_band, self.eval_contact_band = contact_band, eval_contact_band
        self.follow_min_move = follow_min_move
        self.inner_steps, self.inner_iterations = inner_steps, inner_iterations
        self.eval_inner_iterations = eval_inner_iterations
        self.log_eta = nn.Parameter(torch.tensor(math.log(eta)))
        self.gamma_logit = nn.Parameter(torch.tensor(math.log(gamma / (1.0 - gamma))))

    @property
    def eta(self) -> Tensor:
        return self.log_eta.exp()

    @property
    def gamma(self) -> Tensor:
        return torch.sigmoid(self.gamma_logit)

    def forward(self, x: Tensor, cloth: Cloth, *, f_hat: Tensor | None, steps: int, trace: list | None = None,
                bodies: BodySurface | None = None, body_index: Tensor | None = None,
                bounds: list | None = None) -> Tensor:
        """Run `steps` solver steps from x (ΣV, 3) [m]; f̂ (ΣV, 3) [N] or None (pure relaxation).

        bodies / body_index (ΣV,): the posed bodies and each vertex's body, for the two-level
        solver's contact term (ignored by the explicit one; None = no contact). If `trace` is a
        list, the state after each step is appended to it; if `bounds` is, the two-level solver
        appends the `DistanceBound` of its last full body query (the samples: vertices, then face
        centroids), which lets later queries skip the samples far from the body.
        """
        if self.kind is SolverKind.TWO_LEVEL:
            return self._two_level(x, cloth, f_hat, steps, trace, bodies, body_index, bounds)
        eta, gamma = self.eta.to(x.dtype), self.gamma.to(x.dtype)
        step = eta
        for t in range(steps):
            force = internal_forces(x, cloth)
            if f_hat is not None and self._carries_f_hat(t):
                force = force + f_hat
            x = x + self._clip(step * force)
            step = step * gamma
            if trace is not None:
                trace.append(x)
        return x

    def planes_schedule(self) -> tuple[int, bool]:
        """(requery_every, follow_planes) of the current mode: training's, or eval mode's."""
        if self.training:
            return self.requery_every, self.follow_planes
        return self.eval_requery_every, self.eval_follow_planes

    def _carries_f_hat(self, t: int) -> bool:
        return self.f_hat_steps is None or t < self.f_hat_steps

    def _clip(self, move: Tensor) -> Tensor:
        return clip_moves(move, self.max_step)

    @one_blas_thread()  # the coarse space's band factorisations and solves: limited once per solve, not per call
    def _two_level(self, x: Tensor, cloth: Cloth, f_hat: Tensor | None, steps: int, trace: list | None,
                   bodies: BodySurface | None, body_index: Tensor | None, bounds: list | None) -> Tensor:
        eta, gamma = self.eta.to(x.dtype), self.gamma.to(x.dtype)
        problem = self._relaxation(cloth, f_hat, self.contact_band if self.training else self.eval_contact_band,
                                   active_links=True)
        coarse = CoarseSpace(cloth, levels=self.coarse_levels, smoothing=self.coarse_smoothing)
        owner = cloth.vert_garment
        per_garment = cloth.sum_vertex_field

        requery_every, follow_planes = self.planes_schedule()
        step = eta
        phi = None
        direction = last_z = last_force = None  # the previous conjugate direction, preconditioned force, force
        for t in range(steps):
            if f_hat is not None and t == self.f_hat_steps:
                problem.drop_f_hat()
                phi = None  # the conjugation goes on: PR+ restarts if needed
            if bodies is not None and t % requery_every == 0:
                problem.follow_layers(x)  # a multi-piece garment's layer pairs where its pieces are now
                problem.requery(x, bodies, body_index)
                phi = None
            elif bodies is not None and follow_planes:
                change = problem.requery(x, bodies, body_index, local=True)
                phi = None if phi is None else phi + change  # Φ at x on the followed planes, without a new evaluation
            refactor = t % self.refactor_every == 0 or t < self.refactor_first
            force, contact, inverse, pairs = problem.step_terms(x, pairs=coarse.pair_layout if refactor else None)
            if refactor:
                coarse.factor(x, contact, pairs, link_weight=problem.link_weight)
            precondition = partial(_precondition, inverse, coarse)
            iterations = self.inner_iterations if self.training else self.eval_inner_iterations
            if t < self.inner_steps and iterations > 1:
                z = _truncated_newton(precondition, coarse.stiffness_product, force, iterations, per_garment, owner)
            else:
                z = precondition(force)
            if direction is not None:
                with torch.no_grad():  # Polak-Ribière+, preconditioned; the history is not differentiated
                    beta = per_garment(z.detach() * (force.detach() - last_force))
                    beta = (beta / per_garment(last_z * last_force).clamp_min(torch.finfo(x.dtype).tiny)).clamp(0.0, 1.0)
                conjugate = z + beta[owner, None] * direction
                with torch.no_grad():
                    uphill = per_garment(conjugate.detach() * force.detach()) <= 0  # not a descent direction: restart
                z_dir = torch.where(uphill[owner, None], z, conjugate)
            else:
                z_dir = z
            move = problem.short_of_margin(self._clip(step * z_dir), x)
            x0 = x.detach()
            alpha, phi = self._line_search(problem.potential, x0, problem.potential(x0) if phi is None else phi,
                                           move.detach(), per_garment(move.detach() * force.detach()), owner)
            x = x + move * alpha[owner, None]
            direction, last_z, last_force = z_dir.detach(), z.detach(), force.detach()
            step = step * gamma
            if trace is not None:
                trace.append(x)
        if bounds is not None and problem.bound is not None:
            bounds.append(problem.bound)
        return x

    @torch.no_grad()
    def preconditioner(self, x: Tensor, cloth: Cloth, *, bodies: BodySurface | None = None,
                       body_index: Tensor | None = None) -> Callable[[Tensor], Tensor]:
        """The two-level solver's preconditioner C at positions x (ΣV, 3) [m], as the linear map
        of forces (ΣV, 3) [N] to moves [m] that a first solver step from x applies to F: block
        Jacobi on the stiffness blocks plus the coarse correction, with the body contact's blocks
        on planes queried at x (bodies / body_index as in `forward`; None: no contact).

        C is built once and held constant: the map is differentiable in its argument, not in x.
        """
        _, inverse, coarse = self._first_step(x, cloth, bodies, body_index)
        return partial(_precondition, inverse, coarse)

    @torch.no_grad()
    def step_parts(self, x: Tensor, cloth: Cloth, *, bodies: BodySurface | None = None,
                   body_index: Tensor | None = None, query: SurfaceQuery | None = None,
                   newton_iterations: int = 0, layer_slide: float | None = None) -> tuple[Tensor, ...]:
        """The two parts of a first two-level step's direction C F at x (ΣV, 3) [m], F = −∇Φ
        without f̂ (body contact on planes queried at x; bodies / body_index as in `forward`):
        the block-Jacobi move K⁻¹F and the coarse correction's move P (Pᵀ K P)⁻¹ Pᵀ F, each
        (ΣV, 3) [m], each vertex's clipped to `max_step` as a step's (a patch out of the body's
        reach has next to no coarse stiffness: its move under gravity alone is unbounded), not
        differentiated. query: x's samples' body query, made already (`physics.contact.query_samples`
        or `query_samples_near` with a reach ≥ the contact band and ε: the same parts).
        newton_iterations: k > 0 adds a third part, the truncated Newton move z ≈ K⁻¹F of k
        conjugate-gradient iterations preconditioned by C (as the solver's first steps make it),
        clipped the same way. layer_slide: the layer pairs' tangential share β in the step's
        preconditioner (`physics.forces.links`; None: the solver's own)."""
        force, inverse, coarse = self._first_step(x, cloth, bodies, body_index, query, layer_slide)
        parts = (self._clip((inverse @ force.unsqueeze(-1)).squeeze(-1)), self._clip(coarse.solve(force)))
        if not newton_iterations:
            return parts
        owner = cloth.vert_garment
        newton = _truncated_newton(partial(_precondition, inverse, coarse), coarse.stiffness_product, force,
                                   newton_iterations, cloth.sum_vertex_field, owner)
        return parts + (self._clip(newton),)

    def _first_step(self, x: Tensor, cloth: Cloth, bodies: BodySurface | None, body_index: Tensor | None,
                    query: SurfaceQuery | None = None,
                    layer_slide: float | None = None) -> tuple[Tensor, Tensor, CoarseSpace]:
        """F at x, the inverse stiffness blocks and the coarse space factored at x."""
        if self.kind is not SolverKind.TWO_LEVEL:
            raise ValueError(f"the preconditioner belongs to the two_level solver; this solver is {self.kind.value}")
        problem = self._relaxation(cloth, None, self.contact_band, layer_slide=layer_slide)
        if bodies is not None:
            problem.requery(x, bodies, body_index, query=query)
        coarse = CoarseSpace(cloth, levels=self.coarse_levels, smoothing=self.coarse_smoothing,
                             layer_slide=layer_slide)
        force, contact, inverse, pairs = problem.step_terms(x, pairs=coarse.pair_layout)
        coarse.factor(x, contact, pairs)
        return force, inverse, coarse

    def _relaxation(self, cloth: Cloth, f_hat: Tensor | None, band: float, *,
                    layer_slide: float | None = None, active_links: bool = False) -> Relaxation:
        return Relaxation(cloth, f_hat, margin=self.margin, stiffness=self.contact_stiffness, band=band,
                          min_move=self.follow_min_move, reach=max(band, self.contact_band), layer_slide=layer_slide,
                          active_links=active_links)

    @torch.no_grad()
    def _line_search(self, potential, x0: Tensor, phi0: Tensor, move: Tensor, gain: Tensor,
                     owner: Tensor) -> tuple[Tensor, Tensor]:
        """Step length α per garment along `move` (gain = F·move = −dΦ/dα at 0, (G,)): the minimum
        of the parabola through Φ(0), its slope and Φ(1), clamped to [1/20, 4], where that lowers Φ
        below both Φ(0) and Φ(1); else 1, halved up to `max_halvings` times while Φ does not drop;
        else 0. Returns α (G,) and Φ after the step (G,)."""
        phi1 = potential(x0 + move)
        curvature = phi1 - phi0 + gain  # Φ(1) − Φ(0) − Φ'(0)
        vertex = torch.where(curvature > 0, gain / (2.0 * curvature).clamp_min(torch.finfo(x0.dtype).tiny),
                             torch.full_like(gain, 4.0)).clamp(0.05, 4.0).to(x0.dtype)
        phi_vertex = potential(x0 + move * vertex[owner, None])
        use_vertex = (phi_vertex < phi1) & (phi_vertex < phi0)
        alpha = torch.where(use_vertex, vertex, torch.ones_like(vertex))
        phi = torch.where(use_vertex, phi_vertex, phi1)
        done = phi < phi0
        for _ in range(self.max_halvings):
            if bool(done.all()):
                break
            alpha = torch.where(done, alpha, 0.5 * alpha)
            trial = potential(x0 + move * alpha[owner, None])
            lower = ~done & (trial < phi0)
            phi, done = torch.where(lower, trial, phi), done | lower
        return torch.where(done, alpha, torch.zeros_like(alpha)), torch.where(done, phi, phi0)


def clip_moves(move: Tensor, max_length: float) -> Tensor:
    """Each vertex's move (V, 3) [m] shortened to at most `max_length` [m], its direction kept
    (0: unclipped)."""
    if not max_length:
        return move
    length = move.norm(dim=-1, keepdim=True)
    return move * (max_length / length.clamp_min(max_length))


def _truncated_newton(precondition: Callable[[Tensor], Tensor], stiffness: Callable[[Tensor], Tensor], force: Tensor,
                      iterations: int, per_garment: Callable[[Tensor], Tensor], owner: Tensor) -> Tensor:
    """z ≈ K⁻¹ F (V, 3) [m] by `iterations` conjugate-gradient iterations from z = 0, each
    garment on its own, preconditioned by C (`precondition`); K (`stiffness`) and C linear maps
    of per-vertex fields. The coefficients come from detached values: z is a linear map of F."""
    tiny = torch.finfo(torch.float64).tiny
    residual, z = force, torch.zeros_like(force)
    preconditioned = precondition(residual)
    direction = preconditioned
    with torch.no_grad():
        rz = per_garment((residual.detach() * preconditioned.detach()).double())
    for k in range(iterations):
        curved = stiffness(direction)
        with torch.no_grad():
            curvature = per_garment((direction.detach() * curved.detach()).double())
            alpha = torch.where(curvature > 0, rz / curvature.clamp_min(tiny), torch.zeros_like(rz)).to(force.dtype)
        z = z + alpha[owner, None] * direction
        if k == iterations - 1:
            break
        residual = residual - alpha[owner, None] * curved
        preconditioned = precondition(residual)
        with torch.no_grad():
            rz_next = per_garment((residual.detach() * preconditioned.detach()).double())
            beta = (rz_next / rz.clamp_min(tiny)).to(force.dtype)
        direction = preconditioned + beta[owner, None] * direction
        rz = rz_next
    return z


def _precondition(stiffness_inverse: Tensor, coarse: CoarseSpace, force: Tensor) -> Tensor:
    """C F = K⁻¹ F + P (Pᵀ K P)⁻¹ Pᵀ F: forces (V, 3) [N] → moves (V, 3) [m], with K⁻¹ from the
    per-vertex inverse blocks (V, 3, 3) and a factored coarse space."""
    return (stiffness_inverse @ force.unsqueeze(-1)).squeeze(-1) + coarse.solve(force)
