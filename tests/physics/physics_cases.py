"""Deformed states, rotations, the force-against-energy check and the assembly of pair-term
Hessians shared by the physics tests."""

import pytest
import torch

from physdrape.geometry.garment import Garment


def deformed(garment: Garment, *, seed: int, scale: float = 0.02) -> torch.Tensor:
    """A random non-rest state: a smooth stretch and twist plus per-vertex noise, float64."""
    gen = torch.Generator().manual_seed(seed)
    x = garment.rest.clone()
    stretch = torch.tensor([1.15, 0.9, 1.05], dtype=x.dtype)
    x = x * stretch + 0.3 * torch.sin(5.0 * x[:, [1, 2, 0]])
    return x + scale * torch.randn(x.shape, generator=gen, dtype=x.dtype)


def random_rotation(seed: int) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.randn(3, 3, generator=torch.Generator().manual_seed(seed), dtype=torch.float64))
    return q * torch.sign(torch.linalg.det(q))


def assert_force_is_negative_gradient(energy, force, x: torch.Tensor, *, seed: int, min_gradient: float) -> None:
    """force(x) equals −∇ energy(x).sum() by autograd, and along 5 random directions by float64
    central differences; `min_gradient` guards against a stationary test point, where the
    comparison would prove nothing."""
    xg = x.detach().clone().requires_grad_()
    (grad,) = torch.autograd.grad(energy(xg).sum(), xg)
    f = force(x.detach())
    assert grad.abs().max() > min_gradient, "test point is stationary: the comparison would prove nothing"
    torch.testing.assert_close(f, -grad, rtol=1e-12, atol=1e-14)
    h = 1e-6
    gen = torch.Generator().manual_seed(seed)
    for _ in range(5):
        d = torch.randn(x.shape, generator=gen, dtype=x.dtype)
        d /= d.norm()
        fd = (energy(x.detach() + h * d).sum() - energy(x.detach() - h * d).sum()) / (2 * h)
        assert abs(float(fd)) > 1e-7, "finite-difference signal is zero"
        assert float(-(f * d).sum()) == pytest.approx(float(fd), rel=1e-7, abs=1e-12)


def assembled_pair_hessian(pairs: torch.Tensor, blocks: torch.Tensor, num_verts: int) -> torch.Tensor:
    """The dense Hessian (3V, 3V) of a term on vertex pairs (a, b) whose energy depends on x_a − x_b:
    each pair's 3×3 block h enters at (a, a) and (b, b), and −h at (a, b) and (b, a)."""
    out = torch.zeros(3 * num_verts, 3 * num_verts, dtype=blocks.dtype)
    for (a, b), h in zip(pairs.tolist(), blocks):
        for r, c, sign in ((a, a, 1), (b, b, 1), (a, b, -1), (b, a, -1)):
            out[3 * r:3 * r + 3, 3 * c:3 * c + 3] += sign * h
    return out

