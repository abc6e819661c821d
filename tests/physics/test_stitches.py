"""Stitches (physics.stitches): forces = −∇E (autograd and central differences, float64), exact
PSD Hessian blocks, slack below the rest distance, and their place in the shared energy."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from physics_cases import (
    assembled_pair_hessian,
    assert_force_is_negative_gradient,
    deformed,
)

from physdrape.physics import Cloth, energy_terms, internal_energy, internal_forces
from physdrape.physics.stitches import (
    Stitches,
    stitch_blocks,
    stitch_energy,
    stitch_forces,
    stitch_pair_blocks,
)


def make_stitches(garment, x: torch.Tensor, seed: int = 0, count: int = 10, *, taut: bool = True) -> Stitches:
    gen = torch.Generator().manual_seed(seed)
    perm = torch.randperm(garment.num_verts, generator=gen)[:2 * count]
    pairs = perm.reshape(count, 2)
    r = (x[pairs[:, 0]] - x[pairs[:, 1]]).norm(dim=-1)
    rest = r * (0.5 if taut else 1.5)
    return Stitches(pairs=pairs, rest=rest, stiffness=10.0 + 50.0 * torch.rand(count, generator=gen, dtype=torch.float64))


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
@pytest.mark.parametrize("seed", [0, 1])
def test_stitch_force_equals_negative_gradient(mesh, seed, request):
    garment = request.getfixturevalue(mesh)
    x = deformed(garment, seed=seed)
    stitches = make_stitches(garment, x, seed)
    assert_force_is_negative_gradient(lambda y: stitch_energy(y, stitches), lambda y: stitch_forces(y, stitches), x,
                                      seed=seed + 9, min_gradient=1e-4)


def test_stitch_hessian_is_exact_and_psd(sheet):
    x = deformed(sheet, seed=3)
    stitches = make_stitches(sheet, x, 3, count=3)
    full = torch.autograd.functional.hessian(lambda y: stitch_energy(y, stitches).sum(), x)
    full = full.reshape(sheet.num_verts * 3, sheet.num_verts * 3)
    assembled = assembled_pair_hessian(stitches.pairs, stitch_pair_blocks(x, stitches), sheet.num_verts)
    assert full.abs().max() > 1.0
    torch.testing.assert_close(assembled, full, rtol=1e-9, atol=1e-9)
    assert float(torch.linalg.eigvalsh(stitch_pair_blocks(x, stitches)).min()) >= -1e-12
    diag = stitch_blocks(x, stitches)
    for v in range(sheet.num_verts):
        torch.testing.assert_close(diag[v], full[3 * v:3 * v + 3, 3 * v:3 * v + 3], rtol=1e-9, atol=1e-9)


def test_slack_stitches_do_nothing(tube):
    x = deformed(tube, seed=5)
    slack = make_stitches(tube, x, 5, taut=False)
    assert float(stitch_energy(x, slack).abs().max()) == 0.0
    assert float(stitch_forces(x, slack).abs().max()) == 0.0
    assert float(stitch_pair_blocks(x, slack).abs().max()) == 0.0


def test_stitches_are_part_of_the_shared_energy(tube):
    x = deformed(tube, seed=6)
    stitches = make_stitches(tube, x, 6)
    cloth = Cloth.build(tube)
    stitched = replace(cloth, stitches=stitches)
    e = stitch_energy(x, stitches).sum()
    assert float(e) > 1e-6
    assert float(energy_terms(x, stitched)["stitch"]) == pytest.approx(float(e), rel=1e-12)
    assert float(internal_energy(x, stitched) - internal_energy(x, cloth)) == pytest.approx(float(e), rel=1e-9)
    torch.testing.assert_close(internal_forces(x, stitched) - internal_forces(x, cloth), stitch_forces(x, stitches))
    assert stitched.to(torch.float32).stitches.rest.dtype == torch.float32


def test_oracle_minimises_the_stitched_energy(tube):
    """Newton with the stitches' exact Hessian pulls stitched vertices of a tube together."""
    from physdrape.geometry.proximity import BodySurface
    from physdrape.physics import relax

    verts = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64) * 0.01 + 5.0
    bodies = BodySurface(verts, torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))  # far: no contact
    x = tube.rest.clone()
    top = torch.argsort(x[:, 1], descending=True)[:2]
    pairs = top[None]
    stitches = Stitches(pairs=pairs, rest=torch.zeros(1, dtype=torch.float64),
                        stiffness=torch.full((1,), 500.0, dtype=torch.float64))
    cloth = replace(Cloth.build(tube), stitches=stitches, gravity=torch.zeros(1, 3, dtype=torch.float64))
    start = float((x[pairs[0, 0]] - x[pairs[0, 1]]).norm())
    res = relax(x, cloth, bodies, torch.zeros(1, dtype=torch.int64), max_iters=30)
    end = float((res.x[pairs[0, 0]] - res.x[pairs[0, 1]]).norm())
    assert "stitch" in res.energy_terms
    assert end < 0.5 * start, (start, end)
