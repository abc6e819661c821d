"""Zero energy at rest, rigid-motion invariance, relabelling invariance, batches = singles."""

import math

import pytest
import torch
from physics_cases import deformed, random_rotation

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.physics import Cloth, Material, bend_energy, bend_forces, dihedral_angle, internal_forces, strain_energy, strain_forces
from physdrape.physics.forces import energy_terms


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
def test_zero_strain_energy_and_force_at_rest(mesh, request):
    garment = request.getfixturevalue(mesh)
    cloth = Cloth.build(garment)
    x = garment.rest
    assert strain_energy(x, cloth).abs().max() < 1e-20
    assert strain_forces(x, cloth).abs().max() < 1e-12
    # A rigidly moved rest state is still at rest.
    moved = x @ random_rotation(1).T + torch.tensor([0.3, -1.0, 2.0], dtype=x.dtype)
    assert strain_energy(moved, cloth).abs().max() < 1e-18
    assert strain_forces(moved, cloth).abs().max() < 1e-12


def test_zero_bend_energy_and_force_for_a_flat_rest_state(sheet):
    # The rest dihedral angle is flat (DESIGN.md Sec. 2, as in SNUG/DrapeNet): a flat template has
    # no bending energy at rest, and neither has any rigid motion of it.
    cloth = Cloth.build(sheet)
    for x in (sheet.rest, sheet.rest @ random_rotation(2).T + 0.5):
        assert bend_energy(x, cloth).abs().max() < 1e-20
        assert bend_forces(x, cloth).abs().max() < 1e-12


def test_curved_template_keeps_bending_energy_at_rest(tube):
    # With a flat rest angle a curved template is not bending-free at rest: each axial hinge of a
    # regular n-gon tube is folded by 2π/n.
    theta = dihedral_angle(tube.rest, tube.hinges).abs()
    folded = theta > 1e-9
    assert folded.any()
    torch.testing.assert_close(theta[folded], torch.full_like(theta[folded], 2 * math.pi / 9), rtol=1e-12, atol=0)
    cloth = Cloth.build(tube)
    assert bend_energy(tube.rest, cloth).sum() > 0


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
def test_rigid_motion_invariance(mesh, request):
    garment = request.getfixturevalue(mesh)
    cloth = Cloth.build(garment)
    x = deformed(garment, seed=2)
    R = random_rotation(5)
    moved = x @ R.T + torch.tensor([1.0, 2.0, -0.5], dtype=x.dtype)
    for energy, force in ((strain_energy, strain_forces), (bend_energy, bend_forces)):
        e, e_moved = energy(x, cloth), energy(moved, cloth)
        assert e.abs().max() > 0
        torch.testing.assert_close(e_moved, e, rtol=1e-10, atol=1e-14)
        torch.testing.assert_close(force(moved, cloth), force(x, cloth) @ R.T, rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
def test_relabelling_vertices_and_faces(mesh, request):
    garment = request.getfixturevalue(mesh)
    gen = torch.Generator().manual_seed(0)
    vperm = torch.randperm(garment.num_verts, generator=gen)
    fperm = torch.randperm(garment.num_faces, generator=gen)
    inverse = torch.argsort(vperm)  # new index of each old vertex
    faces = inverse[garment.faces[fperm]]
    # Also rotate each face's corner order: the physics may not depend on which corner is first.
    faces = torch.roll(faces, shifts=1, dims=1)
    relabelled = Garment.from_mesh(garment.rest[vperm], faces)
    cloth, cloth_r = Cloth.build(garment), Cloth.build(relabelled)
    x = deformed(garment, seed=3)
    x_r = x[vperm]
    for name, value in energy_terms(x, cloth).items():
        torch.testing.assert_close(energy_terms(x_r, cloth_r)[name], value, rtol=1e-10, atol=1e-15)
    torch.testing.assert_close(internal_forces(x_r, cloth_r), internal_forces(x, cloth)[vperm], rtol=1e-9, atol=1e-13)


def test_packed_batch_equals_garments_alone(sheet, tube):
    silk = Material(mu=1.6e4, lam=2e4, k_bend=2e-6, density=0.05)
    batch = GarmentBatch.pack([sheet, tube])
    cloth = Cloth.build(batch, [Material(), silk])
    x_sheet, x_tube = deformed(sheet, seed=4), deformed(tube, seed=5)
    f_batch = internal_forces(torch.cat([x_sheet, x_tube]), cloth)
    f_sheet, f_tube = batch.split(f_batch)
    torch.testing.assert_close(f_sheet, internal_forces(x_sheet, Cloth.build(sheet)), rtol=0, atol=0)
    torch.testing.assert_close(f_tube, internal_forces(x_tube, Cloth.build(tube, silk)), rtol=0, atol=0)
    terms = energy_terms(torch.cat([x_sheet, x_tube]), cloth)
    for name, value in terms.items():
        assert value.shape == (2,)
        torch.testing.assert_close(value[0], energy_terms(x_sheet, Cloth.build(sheet))[name][0])
        torch.testing.assert_close(value[1], energy_terms(x_tube, Cloth.build(tube, silk))[name][0])


def test_leading_batch_dimension_equals_loop(sheet):
    cloth = Cloth.build(sheet)
    xs = torch.stack([deformed(sheet, seed=s) for s in range(3)])
    batched = internal_forces(xs, cloth)
    for k in range(3):
        torch.testing.assert_close(batched[k], internal_forces(xs[k], cloth), rtol=1e-12, atol=1e-15)
    assert energy_terms(xs, cloth)["strain"].shape == (3, 1)
