"""The preconditioner's Warp kernels on every available device: the CPU's blocks, where the
garment lives."""

from __future__ import annotations

import pytest
import torch
from device_params import DEVICES

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import open_cylinder
from physdrape.physics import Cloth
from physdrape.physics.majorant import pair_blocks, vertex_blocks


@pytest.mark.parametrize("device", DEVICES)
def test_blocks_on_device_match_the_cpu(device):
    garment = Garment.from_mesh(*open_cylinder(8, 16, radius=0.12, length=0.3), dtype=torch.float64)
    cloth = Cloth.build(garment)
    gen = torch.Generator().manual_seed(0)
    x = garment.rest * torch.tensor([1.05, 0.95, 1.0], dtype=torch.float64)
    x = x + 2e-3 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    faces = cloth.faces.shape[0]
    pairs = torch.arange(9 * faces, dtype=torch.int32).reshape(faces, 9)
    want_vertex, want_pairs = vertex_blocks(x, cloth), pair_blocks(x, cloth, pairs, 9 * faces)
    on = Cloth.build(garment.to(device=device))
    got_vertex = vertex_blocks(x.to(device), on)
    got_pairs = pair_blocks(x.to(device), on, pairs.to(device), 9 * faces)
    assert got_vertex.device.type == device and got_pairs.device.type == device
    scale = want_pairs.abs().max().item()
    # atomic sums may add in another order on a GPU
    torch.testing.assert_close(got_vertex.cpu(), want_vertex, rtol=1e-12, atol=1e-12 * scale)
    torch.testing.assert_close(got_pairs.cpu(), want_pairs, rtol=1e-12, atol=1e-12 * scale)


@pytest.mark.parametrize("device", DEVICES)
def test_pair_product_is_the_assembled_matrix_times_the_field_and_its_adjoint(device):
    """Random non-symmetric blocks on random vertex pairs (repeats included): K v against the dense
    assembly, and the gradient against Kᵀ, float64."""
    from physdrape.physics.majorant import pair_product

    gen = torch.Generator().manual_seed(3)
    verts, pairs = 7, 20
    blocks = torch.randn(pairs, 3, 3, generator=gen, dtype=torch.float64)
    ends = torch.randint(0, verts, (pairs, 2), generator=gen, dtype=torch.int32)
    dense = torch.zeros(3 * verts, 3 * verts, dtype=torch.float64)
    for (a, b), block in zip(ends.tolist(), blocks):
        dense[3 * a:3 * a + 3, 3 * b:3 * b + 3] += block
    v = torch.randn(verts, 3, generator=gen, dtype=torch.float64, device=device, requires_grad=True)
    out = pair_product(blocks.to(device), ends.to(device), v)
    torch.testing.assert_close(out.detach().cpu().reshape(-1), dense @ v.detach().cpu().reshape(-1), rtol=1e-12,
                               atol=1e-12)
    weight = torch.randn(verts, 3, generator=gen, dtype=torch.float64)
    (out * weight.to(device)).sum().backward()
    torch.testing.assert_close(v.grad.cpu().reshape(-1), dense.T @ weight.reshape(-1), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("device", DEVICES)
def test_add_blocks_adds_each_block_at_its_row_as_index_add_does(device):
    """Distinct rows among more blocks: the same blocks bit for bit as torch's index_add_, the rows
    not named untouched; a mismatch of rows and blocks is refused."""
    from physdrape.physics.majorant import add_blocks

    gen = torch.Generator().manual_seed(4)
    blocks = torch.randn(30, 3, 3, generator=gen, dtype=torch.float64)
    rows = torch.randperm(30, generator=gen)[:12]
    add = torch.randn(12, 3, 3, generator=gen, dtype=torch.float64)
    want = blocks.clone().index_add_(0, rows, add)
    got = blocks.to(device)
    add_blocks(got, rows.to(device=device, dtype=torch.int32), add.to(device))
    assert torch.equal(got.cpu(), want)
    assert torch.equal(got.cpu()[~torch.isin(torch.arange(30), rows)], blocks[~torch.isin(torch.arange(30), rows)])
    with pytest.raises(ValueError, match="one added block per row"):
        add_blocks(got, rows[:5].to(device=device, dtype=torch.int32), add.to(device))
    with pytest.raises(ValueError, match="int32 rows"):
        add_blocks(got, rows.to(device), add.to(device))
