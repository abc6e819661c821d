"""The learnable stretching solver (paper Eq. 10) on the analytic internal forces."""

from __future__ import annotations

import enum
import math

import torch
from torch import Tensor, nn

from physdrape.geometry.proximity import BodySurface
from physdrape.physics.cloth import Cloth
from physdrape.physics.collision import DEFAULT_MARGIN, DEFAULT_STIFFNESS
from physdrape.physics.forces import internal_energy, internal_forces
from physdrape.physics.hessians import vertex_blocks


class SolverKind(str, enum.Enum):
    """How the solver turns forces into steps (see `StretchingSolver`)."""

    EXPLICIT = "explicit"  # the paper's Eq. 10 as written: a scalar compliance η [m/N]
    JACOBI = "jacobi"  # block-Jacobi preconditioned: a per-vertex compliance η·K_i⁻¹, with contact


class StretchingSolver(nn.Module):
    """X^{t+1} = X^t + η γ^t C_t (F(X^t) + f̂), t = 0 … T−1.

    f̂ is the GNN's estimate of the forces the explicit model lacks (body support, contact,
    unresolved stress; DESIGN.md Sec. 3.5), held fixed over the T steps, so the solver relaxes
    toward F = −f̂. η > 0 is exp-parametrised, γ ∈ (0, 1) sigmoid-parametrised.

    - ``kind="explicit"`` (the paper's Eq. 10): C = I, F = F_int, η a compliance in m/N.
    - ``kind="jacobi"``: η is dimensionless and C_t = K(X^t)⁻¹ per vertex, K_i the 3×3 diagonal
      block of a PSD majorant of the Hessian of E_strain + E_bend + E_coll
      (`physics.hessians.vertex_blocks`): each vertex gets the compliance of its own stiffness,
      so one η suits a 3 mm sliver and a 2 cm face, silk and leather alike, where a scalar η
      must be set for the stiffest element and then barely moves the rest. F = F_int + F_coll:
      the DESIGN.md E_coll penalty (the training loss's) on closest-point planes of the body,
      queried every `requery_every` steps, so gravity cannot pull the garment through the body
      mid-solve. Each step is a descent step on each garment's
      Φ = E_strain + E_bend + E_grav + E_coll − f̂·x: where Φ would rise, the garment's step is
      halved (up to `max_halvings` times, else skipped), so no step raises the energy it
      relaxes (on the body planes held at that step). K (a preconditioner) is not
      differentiated; the step is, through F, f̂, η and γ.
      Optional heavy-ball momentum (`momentum`) with restarts, under the same safeguard.

    Stability guard (both kinds): each vertex's step is clipped to `max_step` [m] in length,
    keeping its direction. Kinematic initialisations can stretch edges where the pose pulls the
    skin (armpits, shoulders); StVK forces there reach tens of newtons — thousands of times a
    vertex's weight — and an unclipped explicit step would diverge.

    Args:
        eta: initial η ([m/N] explicit; dimensionless jacobi, 1 = a full block-Jacobi step).
        gamma: initial decay γ.
        max_step: longest move of one vertex in one step [m] (0 disables the guard).
        kind: `SolverKind`.
        margin, contact_stiffness: ε [m] and k_c [J/m³] of the jacobi solver's contact term.
        requery_every: jacobi steps between body queries (the planes are held in between).
        max_halvings: jacobi step halvings before a step that does not lower Φ is skipped.
        momentum: heavy-ball momentum β of the jacobi steps, in [0, 1): each step first tries
            clip(η γ^t K⁻¹F + β·(last accepted move)) and falls back to the plain step (a restart)
            where that does not lower Φ. Jacobi steps relax a garment's short wavelengths at once
            and its long ones (the garment riding up or sliding down as a whole) slowly; momentum
            carries those along (the 8 evaluation instances, no network, T = 15: E_strain
            0.079 J at β = 0, 0.064 J at β = 0.8).
    """

    def __init__(self, *, eta: float = 1e-3, gamma: float = 0.9, max_step: float = 5e-3,
                 kind: SolverKind | str = SolverKind.EXPLICIT, margin: float = DEFAULT_MARGIN,
                 contact_stiffness: float = DEFAULT_STIFFNESS, requery_every: int = 5, max_halvings: int = 6,
                 momentum: float = 0.0) -> None:
        super().__init__()
        if not eta > 0 or not 0 < gamma < 1:
            raise ValueError(f"need eta > 0 and 0 < gamma < 1, got eta={eta}, gamma={gamma}")
        if max_step < 0:
            raise ValueError(f"max_step must be ≥ 0 [m], got {max_step}")
        if requery_every < 1 or max_halvings < 0:
            raise ValueError(f"need requery_every ≥ 1 and max_halvings ≥ 0, got {requery_every}, {max_halvings}")
        if not 0.0 <= momentum < 1.0:
            raise ValueError(f"momentum must be in [0, 1), got {momentum}")
        self.kind = SolverKind(kind)
        self.max_step = max_step
        self.margin, self.contact_stiffness = margin, contact_stiffness
        self.requery_every, self.max_halvings = requery_every, max_halvings
        self.momentum = momentum
        self.log_eta = nn.Parameter(torch.tensor(math.log(eta)))
        self.gamma_logit = nn.Parameter(torch.tensor(math.log(gamma / (1.0 - gamma))))

    @property
    def eta(self) -> Tensor:
        return self.log_eta.exp()

    @property
    def gamma(self) -> Tensor:
        return torch.sigmoid(self.gamma_logit)

    def forward(self, x: Tensor, cloth: Cloth, *, f_hat: Tensor | None, steps: int, trace: list | None = None,
                bodies: BodySurface | None = None, body_index: Tensor | None = None) -> Tensor:
        """Run `steps` solver steps from x (ΣV, 3) [m]; f̂ (ΣV, 3) [N] or None (pure relaxation).

        bodies / body_index (ΣV,): the posed bodies and each vertex's body, for the jacobi
        solver's contact term (ignored by the explicit one; None = no contact). If `trace` is a
        list, the state after each step is appended to it.
        """
        if self.kind is SolverKind.JACOBI:
            return self._jacobi(x, cloth, f_hat, steps, trace, bodies, body_index)
        eta, gamma = self.eta.to(x.dtype), self.gamma.to(x.dtype)
        step = eta
        for _ in range(steps):
            force = internal_forces(x, cloth)
            if f_hat is not None:
                force = force + f_hat
            x = x + self._clip(step * force)
            step = step * gamma
            if trace is not None:
                trace.append(x)
        return x

    def _clip(self, move: Tensor) -> Tensor:
        if not self.max_step:
            return move
        length = move.norm(dim=-1, keepdim=True)
        return move * (self.max_step / length.clamp_min(self.max_step))

    def _jacobi(self, x: Tensor, cloth: Cloth, f_hat: Tensor | None, steps: int, trace: list | None,
                bodies: BodySurface | None, body_index: Tensor | None) -> Tensor:
        eta, gamma = self.eta.to(x.dtype), self.gamma.to(x.dtype)
        k_c, owner = self.contact_stiffness, cloth.vert_garment
        planes: tuple[Tensor, Tensor] | None = None  # closest points and normals of the body, held

        def depth_of(xt: Tensor) -> Tensor | None:
            if planes is None:
                return None
            return (self.margin - ((xt - planes[0]) * planes[1]).sum(-1)).clamp_min(0.0)

        def potential(xt: Tensor) -> Tensor:
            """Φ per garment (G,) [J]."""
            phi = internal_energy(xt, cloth)
            depth = depth_of(xt)
            if depth is not None:
                phi = phi + cloth.sum_per_garment(k_c * depth ** 3, owner)
            if f_hat is not None:
                phi = phi - cloth.sum_per_garment((f_hat * xt).sum(-1), owner)
            return phi

        step = eta
        phi = None  # Φ at x, carried from the accepted trial while the planes are held
        velocity = None  # the last accepted move (heavy-ball momentum; None when momentum is 0)
        for t in range(steps):
            if bodies is not None and t % self.requery_every == 0:
                with torch.no_grad():
                    q = bodies.query(x.detach(), body_index=body_index)
                planes = (q.closest.to(x.dtype), q.normal.to(x.dtype))
                phi = None
            force = internal_forces(x, cloth)
            depth = depth_of(x)
            if depth is not None:
                force = force + (3.0 * k_c * depth * depth)[:, None] * planes[1]
            if f_hat is not None:
                force = force + f_hat
            chol = self._stiffness_factor(x.detach(), cloth, depth, None if planes is None else planes[1])
            plain = step * torch.cholesky_solve(force.unsqueeze(-1), chol).squeeze(-1)
            # the heavy-ball candidate first (if any), then the plain step (a restart of the momentum)
            candidates = [self._clip(plain + self.momentum * velocity)] if velocity is not None else []
            candidates.append(self._clip(plain))
            x0 = x.detach()
            factors, phi = self._descent_factors(potential, x0, potential(x0) if phi is None else phi, candidates, owner)
            accepted = sum(move * factor[owner, None] for move, factor in zip(candidates, factors))
            x = x + accepted
            velocity = accepted if self.momentum else None
            step = step * gamma
            if trace is not None:
                trace.append(x)
        return x

    @torch.no_grad()
    def _stiffness_factor(self, x: Tensor, cloth: Cloth, depth: Tensor | None, normal: Tensor | None) -> Tensor:
        """Cholesky factors of the per-vertex stiffness blocks K_i (strain, bending, contact), (V, 3, 3)."""
        blocks = vertex_blocks(x, cloth)
        if depth is not None:
            contact = 6.0 * self.contact_stiffness * depth.detach()
            blocks = blocks + contact[:, None, None] * normal[:, :, None] * normal[:, None, :]
        # a floor relative to each vertex's own stiffness keeps K_i invertible (a vertex of an
        # unstretched flat patch has a rank-deficient block)
        rel = max(1e-6, 100.0 * torch.finfo(x.dtype).eps)
        floor = rel * blocks.diagonal(dim1=-2, dim2=-1).sum(-1).clamp_min(torch.finfo(x.dtype).tiny)
        return torch.linalg.cholesky(blocks + floor[:, None, None] * torch.eye(3, dtype=x.dtype, device=x.device))

    @torch.no_grad()
    def _descent_factors(self, potential, x0: Tensor, phi0: Tensor, candidates: list[Tensor],
                         owner: Tensor) -> tuple[list[Tensor], Tensor]:
        """The safeguard: per garment, the first candidate move (in order) that lowers Φ within
        `max_halvings` halvings. Returns each candidate's per-garment factor (G,) (0 where not
        taken; all 0 for a garment whose Φ no candidate lowers) and Φ after the step (G,)."""
        phi = phi0.clone()
        done = torch.zeros_like(phi0, dtype=torch.bool)
        factors = []
        for move in candidates:
            trial, factor = move.detach(), torch.ones_like(phi0)
            taken = torch.zeros_like(done)
            for _ in range(self.max_halvings + 1):
                phi_trial = potential(x0 + trial * factor[owner, None])
                lower = ~done & (phi_trial < phi0)
                phi, done, taken = torch.where(lower, phi_trial, phi), done | lower, taken | lower
                if bool(done.all()):
                    break
                factor = torch.where(done, factor, 0.5 * factor)
            factors.append(torch.where(taken, factor, torch.zeros_like(factor)))
        return factors, phi
