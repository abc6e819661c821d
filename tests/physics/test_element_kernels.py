"""The Warp element kernels (`physics.element_kernels`) against their torch twins
(`element_reference`): values, the backward of the forces (Hessian–vector products) against
autograd through the twins and against central differences of the forces, float64; batches,
dtypes and the errors for what they do not support."""

import pytest
import torch
from element_reference import (
    bend_energy,
    bend_forces,
    dihedral_angle,
    strain_energy,
    strain_forces,
)
from physics_cases import deformed

from physdrape import physics
from physdrape.physics import Cloth, Material

SOFT = Material(mu=1.59e4, lam=3.5e3, k_bend=1e-4, density=0.3)
PAIRS = {  # kernel-backed function, its torch twin; all take (x, cloth)
    "strain_energy": (physics.strain_energy, strain_energy),
    "strain_forces": (physics.strain_forces, strain_forces),
    "bend_energy": (physics.bend_energy, bend_energy),
    "bend_forces": (physics.bend_forces, bend_forces),
    "dihedral_angle": (lambda x, c: physics.dihedral_angle(x, c.hinges), lambda x, c: dihedral_angle(x, c.hinges)),
}


@pytest.mark.parametrize("name", PAIRS)
@pytest.mark.parametrize("mesh", ["sheet", "tube"])
def test_kernels_equal_their_torch_twins(name, mesh, request):
    garment = request.getfixturevalue(mesh)
    cloth = Cloth.build(garment, SOFT)
    kernel, twin = PAIRS[name]
    for seed in range(3):
        x = deformed(garment, seed=seed)
        expected = twin(x, cloth)
        assert expected.abs().max() > 0
        torch.testing.assert_close(kernel(x, cloth), expected, rtol=1e-11, atol=1e-13 * float(expected.abs().max()))


@pytest.mark.parametrize("force", ["strain_forces", "bend_forces"])
def test_force_backward_is_the_hessian_vector_product(force, tube):
    cloth = Cloth.build(tube, SOFT)
    kernel, twin = PAIRS[force]
    x = deformed(tube, seed=5)
    v = torch.randn(x.shape, generator=torch.Generator().manual_seed(0), dtype=x.dtype)
    xg = x.clone().requires_grad_()
    (hv,) = torch.autograd.grad((kernel(xg, cloth) * v).sum(), xg)
    (expected,) = torch.autograd.grad((twin(xg, cloth) * v).sum(), xg)
    assert expected.abs().max() > 1e-6
    torch.testing.assert_close(hv, expected, rtol=1e-10, atol=1e-12 * float(expected.abs().max()))
    # vᵀ ∂f/∂x d against central differences of the force along d
    d = torch.randn(x.shape, generator=torch.Generator().manual_seed(1), dtype=x.dtype)
    d /= d.norm()
    h = 1e-6
    fd = ((kernel(x + h * d, cloth) - kernel(x - h * d, cloth)) * v).sum() / (2 * h)
    assert float((hv * d).sum()) == pytest.approx(float(fd), rel=1e-6)


def test_leading_batch_dimensions_and_float32(sheet):
    cloth = Cloth.build(sheet, SOFT)
    xs = torch.stack([deformed(sheet, seed=s) for s in range(4)]).reshape(2, 2, -1, 3)
    for kernel, _ in PAIRS.values():
        batched = kernel(xs, cloth)
        for i in range(2):
            for j in range(2):
                torch.testing.assert_close(batched[i, j], kernel(xs[i, j], cloth), rtol=0, atol=0)
        single = kernel(xs[0, 0].float(), cloth.to(torch.float32))
        assert single.dtype == torch.float32
        torch.testing.assert_close(single.double(), batched[0, 0], rtol=1e-4, atol=1e-6 * float(batched.abs().max()))


def test_a_garment_without_hinges():
    from physdrape.geometry.garment import Garment

    one = Garment.from_mesh(torch.tensor([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]], dtype=torch.float64),
                            torch.tensor([[0, 1, 2]]))
    cloth = Cloth.build(one, SOFT)
    x = one.rest * 1.1
    assert physics.bend_energy(x, cloth).shape == (0,)
    torch.testing.assert_close(physics.bend_forces(x, cloth), torch.zeros_like(x))
    assert float(physics.strain_energy(x, cloth)[0]) > 0


def test_what_the_kernels_do_not_differentiate_is_an_error(sheet):
    cloth = Cloth.build(sheet, SOFT)
    x = deformed(sheet, seed=0).requires_grad_()
    with pytest.raises(RuntimeError, match="differentiable once"):
        torch.autograd.grad(physics.strain_energy(x, cloth).sum(), x, create_graph=True)
    mu = cloth.mu.clone().requires_grad_()
    with pytest.raises(ValueError, match="constants"):
        physics.strain_energy(x, Cloth(**{**cloth.__dict__, "mu": mu}))


def test_cached_coefficient_copies_follow_their_tensors(sheet):
    cloth = Cloth.build(sheet.to(torch.float32), SOFT)
    x = deformed(sheet, seed=2).float()
    before = physics.strain_energy(x, cloth)
    cloth.mu.mul_(2.0)  # an in-place change must not be hidden by the float64 copy made above
    after = physics.strain_energy(x, cloth)
    assert not torch.equal(before, after)
    rebuilt = Cloth.build(sheet.to(torch.float32), SOFT)
    rebuilt.mu.mul_(2.0)
    torch.testing.assert_close(after, physics.strain_energy(x, rebuilt), rtol=0, atol=0)


def test_recorded_launches_follow_new_coefficients_and_do_not_keep_them(sheet):
    """A launch is recorded per constants and replayed; cloths built and dropped one after another
    (their tensors' ids recycled) each get their own energies and forces, forward and backward,
    and a dropped cloth's coefficients are not kept alive by the recorded launches."""
    import gc
    import weakref

    from physdrape.physics import cloth as cloth_module

    x = deformed(sheet, seed=3)
    direction = torch.randn(x.shape, generator=torch.Generator().manual_seed(4), dtype=x.dtype)
    for k in range(6):
        material = Material(mu=1.59e4 * (1 + k), lam=3.5e3, k_bend=1e-4 * (1 + k), density=0.3)
        cloth = Cloth.build(sheet, material)
        xg = x.clone().requires_grad_()
        f = physics.strain_forces(xg, cloth) + physics.bend_forces(xg, cloth)
        (hv,) = torch.autograd.grad(f, xg, grad_outputs=direction)
        xr = x.clone().requires_grad_()
        fr = strain_forces(xr, cloth) + bend_forces(xr, cloth)
        (hvr,) = torch.autograd.grad(fr, xr, grad_outputs=direction)
        torch.testing.assert_close(f, fr, rtol=1e-10, atol=1e-12 * float(fr.abs().max()))
        torch.testing.assert_close(hv, hvr, rtol=1e-8, atol=1e-10 * float(hvr.abs().max()))
        torch.testing.assert_close(physics.strain_energy(x, cloth), strain_energy(x, cloth), rtol=1e-10, atol=0)
        mu = weakref.ref(cloth.mu)
        del cloth, f, hv, fr, hvr, xg, xr
        cloth_module._BUILT.clear()  # the cloths `Cloth.build` keeps for a batch built again
        gc.collect()
        assert mu() is None


def test_the_kernels_atan2_is_within_an_ulp_or_two_and_its_adjoint_exact():
    """The dihedral angle's atan2 (its own rational approximation, `element_kernels`) against
    torch's in every quadrant, on the axes and at extreme ratios; its adjoint is the exact
    derivative."""
    from physdrape.physics.element_kernels import _kernels
    from physdrape.warp_runtime import warp

    wp = warp()
    atan2 = _kernels()["atan2"]

    @wp.kernel
    def apply(y: wp.array(dtype=wp.float64), x: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.float64)):
        i = wp.tid()
        out[i] = atan2(y[i], x[i])

    g = torch.Generator().manual_seed(0)
    angle = (2 * torch.rand(20000, generator=g, dtype=torch.float64) - 1) * torch.pi
    radius = torch.exp(3 * torch.randn(20000, generator=g, dtype=torch.float64))
    y, x = radius * angle.sin(), radius * angle.cos()
    y[:500] *= 1e-12  # near the x axis, both sides
    x[500:1000] *= 1e-12  # near the y axis
    axes = torch.tensor([[0.0, 1.0], [0.0, -1.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 0.0], [1.0, 1.0], [-1.0, -1.0],
                         [0.66, 1.0], [1.0, 0.66]], dtype=torch.float64)
    y, x = torch.cat([y, axes[:, 0]]), torch.cat([x, axes[:, 1]])
    out = torch.zeros_like(y)
    adj_y, adj_x = torch.zeros_like(y), torch.zeros_like(x)
    arrays = [wp.from_torch(t) for t in (y, x, out)]
    wp.launch(apply, dim=len(y), inputs=arrays[:2], outputs=arrays[2:], device="cpu")
    expected = torch.atan2(y, x)
    eps = torch.finfo(torch.float64).eps
    assert bool(((out - expected).abs() <= 2 * eps * expected.abs()).all())
    wp.launch(apply, dim=len(y), inputs=arrays[:2], outputs=arrays[2:], device="cpu", adjoint=True,
              adj_inputs=[wp.from_torch(adj_y), wp.from_torch(adj_x)], adj_outputs=[wp.from_torch(torch.ones_like(y))])
    keep = (x != 0) | (y != 0)
    torch.testing.assert_close(adj_y[keep], (x / (x * x + y * y))[keep], rtol=1e-14, atol=0)
    torch.testing.assert_close(adj_x[keep], (-y / (x * x + y * y))[keep], rtol=1e-14, atol=0)
