"""The learnable stretching solver (paper Eq. 10) on the analytic internal forces."""

from __future__ import annotations

import math

import torch
from torch import Tensor, nn

from physdrape.physics.cloth import Cloth
from physdrape.physics.forces import internal_forces


class StretchingSolver(nn.Module):
    """X^{t+1} = X^t + η γ^t (F_int(X^t) + f̂), t = 0 … T−1.

    f̂ is the GNN's estimate of the forces the explicit model lacks (body support, contact,
    unresolved stress; DESIGN.md Sec. 3.5), held fixed over the T steps, so the solver relaxes
    toward F_int = −f̂. η > 0 [m/N] is exp-parametrised, γ ∈ (0, 1) sigmoid-parametrised.

    Stability guard (ours): each vertex's step η γ^t (F_int + f̂) is clipped to `max_step` [m]
    in length, keeping its direction. Kinematic initialisations stretch edges up to ~4× where the
    pose pulls the skin (armpits, shoulders); StVK forces there reach tens of newtons — thousands
    of times a vertex's weight — and an unclipped explicit step would diverge. Steps of ordinary
    size are unaffected.

    Args:
        eta: initial compliance η [m/N] (stable for the training materials' stiffest fabric).
        gamma: initial decay γ.
        max_step: longest move of one vertex in one step [m] (0 disables the guard).
    """

    def __init__(self, *, eta: float = 1e-3, gamma: float = 0.9, max_step: float = 5e-3) -> None:
        super().__init__()
        if not eta > 0 or not 0 < gamma < 1:
            raise ValueError(f"need eta > 0 and 0 < gamma < 1, got eta={eta}, gamma={gamma}")
        if max_step < 0:
            raise ValueError(f"max_step must be ≥ 0 [m], got {max_step}")
        self.max_step = max_step
        self.log_eta = nn.Parameter(torch.tensor(math.log(eta)))
        self.gamma_logit = nn.Parameter(torch.tensor(math.log(gamma / (1.0 - gamma))))

    @property
    def eta(self) -> Tensor:
        return self.log_eta.exp()

    @property
    def gamma(self) -> Tensor:
        return torch.sigmoid(self.gamma_logit)

    def forward(self, x: Tensor, cloth: Cloth, *, f_hat: Tensor | None, steps: int, trace: list | None = None) -> Tensor:
        """Run `steps` solver steps from x (ΣV, 3) [m]; f̂ (ΣV, 3) [N] or None (pure relaxation).

        If `trace` is a list, the state after each step is appended to it.
        """
        eta, gamma = self.eta.to(x.dtype), self.gamma.to(x.dtype)
        step = eta
        for _ in range(steps):
            force = internal_forces(x, cloth)
            if f_hat is not None:
                force = force + f_hat
            move = step * force
            if self.max_step:
                length = move.norm(dim=-1, keepdim=True)
                move = move * (self.max_step / length.clamp_min(self.max_step))
            x = x + move
            step = step * gamma
            if trace is not None:
                trace.append(x)
        return x
