"""The element and majorant kernels split between threads (`physdrape.threads`): on a packed
batch of garments the parts touch disjoint vertices and give what one thread gives, bit for bit."""

from __future__ import annotations

import pytest
import torch
from physics_cases import deformed

from physdrape import physics
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet
from physdrape.physics import Cloth, Material
from physdrape.physics.majorant import pair_blocks, vertex_blocks


@pytest.fixture
def threads():
    before = torch.get_num_threads()
    yield torch.set_num_threads
    torch.set_num_threads(before)


def _sheets(count: int) -> GarmentBatch:
    return GarmentBatch.pack([Garment.from_mesh(*grid_sheet(40, 30 + k, width=0.6, height=0.5), name=f"sheet{k}")
                              for k in range(count)])


def test_two_threads_give_one_threads_values_and_gradients(threads):
    batch = _sheets(3)
    cloth = Cloth.build(batch, [Material(), Material(mu=8e4, k_bend=4e-4), Material(mu=5e3, k_bend=1e-5)])
    x = torch.cat([deformed(g, seed=k) for k, g in enumerate(batch.garments)])
    v = torch.randn(x.shape, generator=torch.Generator().manual_seed(0), dtype=x.dtype)
    pair_of_corner = torch.arange(9 * cloth.faces.shape[0], dtype=torch.int32).reshape(-1, 9)
    out = {}
    for count in (1, 2):
        threads(count)
        xg = x.clone().requires_grad_()
        values = [physics.strain_energy(xg, cloth), physics.bend_energy(xg, cloth), physics.strain_forces(xg, cloth),
                  physics.bend_forces(xg, cloth)]
        grads = [torch.autograd.grad((value * (v if value.ndim == 2 else 1.0)).sum(), xg)[0] for value in values]
        out[count] = [*values, *grads, vertex_blocks(x, cloth), pair_blocks(x, cloth, pair_of_corner,
                                                                            9 * cloth.faces.shape[0])]
    for one, two in zip(out[1], out[2]):
        assert torch.equal(one.detach(), two.detach())

