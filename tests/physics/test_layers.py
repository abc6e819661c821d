"""The layer order (physics.layers): forces = −∇E (autograd and central differences, float64),
exact PSD pair Hessian, one-sidedness, its place in the shared energy, and the oracle keeping an
outer sheet outside an inner one."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from physics_cases import (
    assembled_pair_hessian,
    assert_force_is_negative_gradient,
    deformed,
)

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.proximity import BodySurface
from physdrape.physics import (
    Cloth,
    energy_terms,
    internal_energy,
    internal_forces,
    relax,
)
from physdrape.physics.layers import (
    DEFAULT_LAYER_GAP,
    DEFAULT_LAYER_STIFFNESS,
    MIN_LAYER_GAP,
    LayerOrder,
    layer_energy,
    layer_forces,
    layer_pair_blocks,
    layer_shortfall,
    push_outer_out,
)


def make_layers(garment, x: torch.Tensor, seed: int = 0, count: int = 10, *, active: bool = True) -> LayerOrder:
    gen = torch.Generator().manual_seed(seed)
    pairs = torch.randperm(garment.num_verts, generator=gen)[:2 * count].reshape(count, 2)
    normal = torch.randn(count, 3, generator=gen, dtype=torch.float64)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    sep = ((x[pairs[:, 0]] - x[pairs[:, 1]]) * normal).sum(-1)
    gap = sep + (0.01 if active else -0.01)
    return LayerOrder(pairs=pairs, normal=normal, gap=gap,
                      stiffness=100.0 + 100.0 * torch.rand(count, generator=gen, dtype=torch.float64))


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
@pytest.mark.parametrize("seed", [0, 1])
def test_layer_force_equals_negative_gradient(mesh, seed, request):
    garment = request.getfixturevalue(mesh)
    x = deformed(garment, seed=seed)
    layers = make_layers(garment, x, seed)
    assert_force_is_negative_gradient(lambda y: layer_energy(y, layers), lambda y: layer_forces(y, layers), x,
                                      seed=seed + 11, min_gradient=1e-3)


def test_layer_hessian_is_exact_psd_and_one_sided(sheet):
    x = deformed(sheet, seed=4)
    layers = make_layers(sheet, x, 4, count=3)
    full = torch.autograd.functional.hessian(lambda y: layer_energy(y, layers).sum(), x)
    full = full.reshape(sheet.num_verts * 3, sheet.num_verts * 3)
    assembled = assembled_pair_hessian(layers.pairs, layer_pair_blocks(x, layers), sheet.num_verts)
    assert full.abs().max() > 10.0
    torch.testing.assert_close(assembled, full, rtol=1e-9, atol=1e-9)
    assert float(torch.linalg.eigvalsh(layer_pair_blocks(x, layers)).min()) >= -1e-12
    apart = make_layers(sheet, x, 4, count=3, active=False)  # already far enough apart: no term
    assert float(layer_energy(x, apart).abs().max()) == 0.0
    assert float(layer_forces(x, apart).abs().max()) == 0.0


def test_layers_are_part_of_the_shared_energy(tube):
    x = deformed(tube, seed=6)
    layers = make_layers(tube, x, 6)
    cloth = Cloth.build(tube)
    layered = replace(cloth, layers=layers)
    e = layer_energy(x, layers).sum()
    assert float(e) > 1e-6
    assert float(energy_terms(x, layered)["layer"]) == pytest.approx(float(e), rel=1e-12)
    assert float(internal_energy(x, layered) - internal_energy(x, cloth)) == pytest.approx(float(e), rel=1e-9)
    torch.testing.assert_close(internal_forces(x, layered) - internal_forces(x, cloth), layer_forces(x, layers))
    assert layered.to(torch.float32).layers.normal.dtype == torch.float32
    assert Cloth.build(tube).with_terms_of(layered).layers is not None


def test_oracle_keeps_the_outer_sheet_outside():
    """Two flat sheets, the outer authored 1 mm above the inner, started 3 mm below it (through it):
    with the layer order the oracle puts the outer back outside; without it, it stays through."""
    n = 6
    g = torch.linspace(0.0, 0.05, n, dtype=torch.float64)
    xx, zz = torch.meshgrid(g, g, indexing="ij")
    grid = torch.stack([xx.reshape(-1), torch.zeros(n * n, dtype=torch.float64), zz.reshape(-1)], -1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            faces += [(a, b, d), (a, d, c)]
    faces = torch.tensor(faces)
    inner = Garment.from_mesh(grid, faces, dtype=torch.float64)
    outer = Garment.from_mesh(grid + torch.tensor([0.0, 1e-3, 0.0], dtype=torch.float64), faces, dtype=torch.float64)
    batch = GarmentBatch.pack([inner, outer])
    cloth = replace(Cloth.build(batch), gravity=torch.zeros(2, 3, dtype=torch.float64))
    pairs = torch.stack([torch.arange(n * n) + n * n, torch.arange(n * n)], 1)
    up = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand(n * n, 3)
    layers = LayerOrder(pairs=pairs, normal=up, gap=torch.full((n * n,), 1e-3, dtype=torch.float64),
                        stiffness=torch.full((n * n,), 1000.0, dtype=torch.float64))
    x = batch.rest.clone()
    x[n * n:, 1] -= 4e-3  # the whole outer sheet through the inner one
    verts = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64) * 0.01 + 5.0
    bodies = BodySurface(verts, torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))  # far: no contact
    body_index = torch.zeros(2, dtype=torch.int64)
    free = relax(x, cloth, bodies, body_index, max_iters=20)
    held = relax(x, replace(cloth, layers=layers), bodies, body_index, max_iters=20)
    assert "layer" in held.energy_terms
    def separation(r):
        return r.x[n * n:, 1] - r.x[:n * n, 1]

    assert float(separation(held).min()) > 0.9e-3
    assert float(separation(free).max()) < -2e-3


def test_layer_order_keeps_the_template_gap_within_bounds():
    pairs = torch.tensor([[0, 1], [2, 3], [4, 5]])
    normal = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand(3, 3)
    built = LayerOrder.build(pairs, normal, separation=torch.tensor([2e-4, 2e-3, 1e-2], dtype=torch.float64))
    torch.testing.assert_close(built.gap, torch.tensor([MIN_LAYER_GAP, 2e-3, DEFAULT_LAYER_GAP], dtype=torch.float64))
    assert built.stiffness.tolist() == [DEFAULT_LAYER_STIFFNESS] * 3
    assert LayerOrder.build(pairs, normal).gap.tolist() == [DEFAULT_LAYER_GAP] * 3


@pytest.mark.parametrize("active", [True, False])
def test_the_links_blocks_majorise_the_stitches_and_layer_pairs_exact_blocks(sheet, active):
    """The preconditioners' link blocks H (`physics.forces.links`) are ≥ each pair's exact 3×3
    block, so [[H, −H], [−H, H]] majorises the pair's Hessian; x-independent, the same whether
    the pairs are active or not."""
    from test_stitches import make_stitches

    from physdrape.physics.forces import links
    from physdrape.physics.stitches import stitch_pair_blocks

    x = deformed(sheet, seed=5)
    layers = make_layers(sheet, x, 5, count=6, active=active)
    stitches = make_stitches(sheet, x, 6, count=6, taut=active)
    cloth = replace(Cloth.build(sheet), stitches=stitches, layers=layers)
    tied = links(cloth)
    assert torch.equal(tied.pairs, torch.cat([stitches.pairs, layers.pairs]))
    exact = torch.cat([stitch_pair_blocks(x, stitches), layer_pair_blocks(x, layers)])
    assert bool((exact.abs().amax(dim=(1, 2)) > 0).all()) == active  # not vacuous where active
    assert torch.linalg.eigvalsh(tied.blocks - exact).min() > -1e-9 * tied.blocks.abs().max()
    # a layer pair's block is stiffest along its normal
    n = layers.normal
    along = torch.einsum("pi,pij,pj->p", n, tied.blocks[len(stitches.pairs):], n)
    torch.testing.assert_close(along, layers.stiffness)


def test_pushing_the_outer_vertices_out_puts_the_layers_in_order_or_within_what_is_allowed(sheet):
    x = deformed(sheet, seed=7)
    layers = make_layers(sheet, x, 7, count=8)  # every pair short of its gap by 1 cm
    assert bool((layer_shortfall(x, layers) > 5e-3).all())
    pushed = push_outer_out(x, layers)
    torch.testing.assert_close(layer_shortfall(pushed, layers), torch.zeros(8, dtype=torch.float64), rtol=0,
                               atol=1e-12)
    moved = pushed - x
    outer = layers.pairs[:, 0]
    assert bool((moved.abs().sum(-1) > 0).sum() == 8) and bool((moved[outer].abs().sum(-1) > 0).all())
    torch.testing.assert_close(moved[outer], 1e-2 * layers.normal, rtol=0, atol=1e-12)  # along n, by the shortfall
    allowed = torch.full((8,), 4e-3, dtype=torch.float64)
    torch.testing.assert_close(layer_shortfall(push_outer_out(x, layers, allowed), layers), allowed, rtol=0, atol=1e-12)
