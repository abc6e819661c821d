"""The grip term (physics.grip): forces = −∇E (autograd and central differences, float64), its
exact Hessian blocks, its place in the shared energy (internal forces, the solver's Φ, the
oracle), and the pipeline building it for a waistband."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from physics_cases import assert_force_is_negative_gradient, deformed

from physdrape.geometry.proximity import BodySurface
from physdrape.physics import (
    Cloth,
    energy_terms,
    internal_energy,
    internal_forces,
    relax,
)
from physdrape.physics.energy import drape_energies
from physdrape.physics.grip import Grip, grip_blocks, grip_energy, grip_forces


def make_grip(garment, seed: int = 0, count: int = 12) -> Grip:
    gen = torch.Generator().manual_seed(seed)
    index = torch.randperm(garment.num_verts, generator=gen)[:count]
    normal = torch.randn(count, 3, generator=gen, dtype=torch.float64)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    anchor = garment.rest[index] + 0.01 * torch.randn(count, 3, generator=gen, dtype=torch.float64)
    stiffness = 50.0 + 100.0 * torch.rand(count, generator=gen, dtype=torch.float64)
    return Grip(index=index, anchor=anchor, normal=normal, stiffness=stiffness)


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
@pytest.mark.parametrize("seed", [0, 1])
def test_grip_force_equals_negative_gradient(mesh, seed, request):
    garment = request.getfixturevalue(mesh)
    grip = make_grip(garment, seed)
    assert_force_is_negative_gradient(lambda y: grip_energy(y, grip), lambda y: grip_forces(y, grip),
                                      deformed(garment, seed=seed), seed=seed + 5, min_gradient=1e-6)


def test_grip_blocks_are_the_exact_hessian_and_leave_the_normal_free(sheet):
    grip = make_grip(sheet, 2, count=4)
    x = deformed(sheet, seed=2)
    full = torch.autograd.functional.hessian(lambda y: grip_energy(y, grip).sum(), x).reshape(
        sheet.num_verts * 3, sheet.num_verts * 3)
    blocks = grip_blocks(grip, sheet.num_verts, dtype=torch.float64)
    dense = torch.block_diag(*blocks)
    assert full.abs().max() > 1.0
    torch.testing.assert_close(dense, full, rtol=1e-10, atol=1e-10)
    # a move along the body normal costs nothing; at the anchor the energy is zero
    moved = x.clone()
    moved[grip.index] = grip.anchor + 0.003 * grip.normal
    assert float(grip_energy(moved, grip).abs().max()) < 1e-18


def test_grip_is_part_of_the_shared_energy(tube):
    cloth = Cloth.build(tube)
    grip = make_grip(tube, 3)
    gripped = replace(cloth, grip=grip)
    x = deformed(tube, seed=4)
    e = grip_energy(x, grip).sum()
    assert float(e) > 1e-6
    assert float(energy_terms(x, gripped)["grip"]) == pytest.approx(float(e), rel=1e-12)
    assert float(internal_energy(x, gripped) - internal_energy(x, cloth)) == pytest.approx(float(e), rel=1e-9)
    torch.testing.assert_close(internal_forces(x, gripped) - internal_forces(x, cloth), grip_forces(x, grip))
    # moved and cast with the cloth
    assert gripped.to(torch.float32).grip.anchor.dtype == torch.float32


def test_oracle_and_energy_see_the_grip(tube):
    """A gripped tube above a small body: the oracle minimises the energy with the grip (its
    gripped vertices stay near their anchors while gravity pulls), and drape_energies reports it."""
    verts = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64) * 0.01 + 5.0
    faces = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    bodies = BodySurface(verts, faces)  # far away: no contact
    cloth = Cloth.build(tube)
    top = torch.argsort(tube.rest[:, 1], descending=True)[:10]
    normal = torch.zeros(len(top), 3, dtype=torch.float64)
    normal[:, 2] = 1.0  # tangent plane = x-y: gravity (−y) acts along it
    grip = Grip(index=top, anchor=tube.rest[top].clone(), normal=normal,
                stiffness=torch.full((len(top),), 200.0, dtype=torch.float64))
    gripped = replace(cloth, grip=grip)
    body_index = torch.zeros(1, dtype=torch.int64)
    free = relax(tube.rest.clone(), cloth, bodies, body_index, max_iters=15)
    held = relax(tube.rest.clone(), gripped, bodies, body_index, max_iters=15)
    assert "grip" in held.energy_terms
    drop_free = float((tube.rest[top, 1] - free.x[top, 1]).mean())
    drop_held = float((tube.rest[top, 1] - held.x[top, 1]).mean())
    assert drop_free > 10 * max(drop_held, 1e-6), (drop_free, drop_held)
    terms = drape_energies(held.x, gripped, bodies, torch.zeros(tube.num_verts, dtype=torch.int64),
                           contact_stiffness=2.5e3, margin=2e-3)
    assert float(terms["grip"]) == pytest.approx(float(held.energy_terms["grip"]), rel=1e-9)
