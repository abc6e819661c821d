"""Every analytic force is −∇ of its energy: autograd and central finite differences, float64
(the body contact's: tests/physics/test_contact.py)."""

import pytest
import torch
from physics_cases import deformed

from physdrape.physics import (
    Cloth,
    Material,
    bend_energy,
    bend_forces,
    gravity_energy,
    gravity_forces,
    internal_energy,
    internal_forces,
    strain_energy,
    strain_forces,
)

TERMS = {
    "strain": (strain_energy, strain_forces),
    "bend": (bend_energy, bend_forces),
    "gravity": (gravity_energy, gravity_forces),
    "internal": (lambda x, c: internal_energy(x, c), internal_forces),
}
SOFT = Material(mu=1.59e4, lam=3.5e3, k_bend=1e-4, density=0.3)


def total(energy, x, cloth):
    return energy(x, cloth).sum()


@pytest.mark.parametrize("term", TERMS)
@pytest.mark.parametrize("mesh", ["sheet", "tube"])
@pytest.mark.parametrize("seed", [0, 1])
def test_force_equals_negative_autograd_gradient(term, mesh, seed, request):
    garment = request.getfixturevalue(mesh)
    cloth = Cloth.build(garment, SOFT)
    energy, force = TERMS[term]
    x = deformed(garment, seed=seed).requires_grad_()
    (grad,) = torch.autograd.grad(total(energy, x, cloth), x)
    f = force(x.detach(), cloth)
    assert grad.abs().max() > 1e-8, "test point is stationary: the comparison would prove nothing"
    torch.testing.assert_close(f, -grad, rtol=1e-9, atol=1e-12 * float(grad.abs().max()))


@pytest.mark.parametrize("term", TERMS)
@pytest.mark.parametrize("mesh", ["sheet", "tube"])
def test_force_matches_central_finite_differences(term, mesh, request):
    garment = request.getfixturevalue(mesh)
    cloth = Cloth.build(garment, SOFT)
    energy, force = TERMS[term]
    x = deformed(garment, seed=7)
    f = force(x, cloth)
    gen = torch.Generator().manual_seed(3)
    h = 1e-6
    for _ in range(5):
        direction = torch.randn(x.shape, generator=gen, dtype=x.dtype)
        direction /= direction.norm()
        fd = (total(energy, x + h * direction, cloth) - total(energy, x - h * direction, cloth)) / (2 * h)
        analytic = -(f * direction).sum()
        assert abs(float(fd)) > 1e-7, "finite-difference signal is zero: not a meaningful test point"
        assert float(analytic) == pytest.approx(float(fd), rel=1e-6, abs=1e-10)


def test_forces_follow_the_input_dtype(sheet):
    cloth32 = Cloth.build(sheet.to(torch.float32))
    x = deformed(sheet, seed=0).float()
    for _, force in TERMS.values():
        assert force(x, cloth32).dtype == torch.float32
    f64 = internal_forces(deformed(sheet, seed=0), Cloth.build(sheet))
    torch.testing.assert_close(internal_forces(x, cloth32).double(), f64, rtol=1e-3, atol=1e-6 * float(f64.abs().max()))
