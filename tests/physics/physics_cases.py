"""Deformed states and rotations shared by the physics tests."""

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
