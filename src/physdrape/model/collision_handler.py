"""The learnable collision handler (paper Eq. 11): push vertices out along the body normal."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from physdrape.geometry.proximity import BodySurface
from physdrape.physics.collision import DEFAULT_MARGIN


class CollisionHandler(nn.Module):
    """x*_i = x_i + δ · ReLU(ε − d_i) · n_i with δ = 1 + softplus(ρ) ≥ 1.

    d_i and n_i come from the exact closest point on the posed body triangles. Which triangle is
    closest is not differentiated; x* is differentiable in x (and δ).

    Args:
        margin: ε [m]; a vertex ends at least ε outside the body along n when δ ≥ 1.
        delta: initial δ (> 1).
    """

    def __init__(self, *, margin: float = DEFAULT_MARGIN, delta: float = 1.05) -> None:
        super().__init__()
        if not margin > 0 or not delta > 1:
            raise ValueError(f"need margin > 0 and delta > 1, got margin={margin}, delta={delta}")
        self.margin = margin
        self.delta_raw = nn.Parameter(torch.tensor(math.log(math.expm1(delta - 1.0))))

    @property
    def delta(self) -> Tensor:
        return 1.0 + F.softplus(self.delta_raw)

    def forward(self, x: Tensor, bodies: BodySurface, body_index: Tensor, *, delta: Tensor | float | None = None) -> Tensor:
        """Project x (ΣV, 3) [m] out of the bodies; `body_index` (ΣV,) names each vertex's body.

        `delta` overrides the learned δ (the Post-Col ablation uses a plain δ = 1).
        """
        query = bodies.query(x, body_index=body_index)
        delta = self.delta.to(x.dtype) if delta is None else delta
        push = delta * (self.margin - query.signed_distance).clamp_min(0.0)
        return x + push[:, None] * query.normal
