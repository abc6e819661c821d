"""Deformed states, rotations and the force-against-energy check shared by the physics tests."""

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

