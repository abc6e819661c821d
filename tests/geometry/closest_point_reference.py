"""Slow torch twin of the Warp closest-point kernel (`physdrape.geometry.closest_point`):
Ericson's region test as batched torch ops, differentiable by autograd."""

import torch
from torch import Tensor


def _safe_div(num: Tensor, den: Tensor) -> Tensor:
    """num / den where den != 0, else 0 (keeps NaNs out of the unselected torch.where branches)."""
    ok = den != 0
    return torch.where(ok, num / torch.where(ok, den, torch.ones_like(den)), torch.zeros_like(num))


def closest_point_on_triangle(x: Tensor, a: Tensor, b: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    """`physdrape.geometry.closest_point.closest_point_on_triangle` in torch ops (same arguments
    and results; Ericson's regions as `torch.where` selections)."""
    ab, ac, ap = b - a, c - a, x - a
    d1 = (ab * ap).sum(-1)
    d2 = (ac * ap).sum(-1)
    bp = x - b
    d3 = (ab * bp).sum(-1)
    d4 = (ac * bp).sum(-1)
    cp = x - c
    d5 = (ab * cp).sum(-1)
    d6 = (ac * cp).sum(-1)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2

    one = torch.ones_like(d1)
    zero = torch.zeros_like(d1)
    # Interior.
    den = va + vb + vc
    v_in = _safe_div(vb, den)
    w_in = _safe_div(vc, den)
    bary = torch.stack([one - v_in - w_in, v_in, w_in], -1)

    def pick(mask: Tensor, new: Tensor, cur: Tensor) -> Tensor:
        return torch.where(mask[..., None], new, cur)

    # Regions in reverse priority order, so the first test in Ericson's order wins.
    w_bc = _safe_div(d4 - d3, (d4 - d3) + (d5 - d6))
    bary = pick((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), torch.stack([zero, one - w_bc, w_bc], -1), bary)
    w_ac = _safe_div(d2, d2 - d6)
    bary = pick((vb <= 0) & (d2 >= 0) & (d6 <= 0), torch.stack([one - w_ac, zero, w_ac], -1), bary)
    bary = pick((d6 >= 0) & (d5 <= d6), torch.stack([zero, zero, one], -1), bary)
    v_ab = _safe_div(d1, d1 - d3)
    bary = pick((vc <= 0) & (d1 >= 0) & (d3 <= 0), torch.stack([one - v_ab, v_ab, zero], -1), bary)
    bary = pick((d3 >= 0) & (d4 <= d3), torch.stack([zero, one, zero], -1), bary)
    bary = pick((d1 <= 0) & (d2 <= 0), torch.stack([one, zero, zero], -1), bary)

    p = bary[..., 0:1] * a + bary[..., 1:2] * b + bary[..., 2:3] * c
    return p, bary
