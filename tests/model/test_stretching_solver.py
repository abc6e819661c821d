"""The stretching solver: the two-level kind is a descent method; gradients; batching (float64)."""

import itertools

import pytest
import torch
from drape_cases import layered_tubes, make_input, tube

from physdrape.model import relaxation
from physdrape.model.stretching_solver import SolverKind, StretchingSolver
from physdrape.physics import Material
from physdrape.physics.coarse_space import CoarseSpace
from physdrape.physics.forces import internal_energy
from physdrape.physics.majorant import vertex_compliance

SILK = Material(mu=1.6e4, lam=2e4, k_bend=2e-6, density=0.05)  # the soft end of the training range


def _tubes():
    return [tube(6, 16, 0.14, dtype=torch.float64, name="a"), tube(5, 13, 0.17, dtype=torch.float64, name="b")]


def _case(radii=(0.15, 0.13), materials=None, stretch=1.08):
    """Two tubes around sphere bodies, stretched radially (float64)."""
    batch = make_input(_tubes(), list(radii), materials, dtype=torch.float64)
    gen = torch.Generator().manual_seed(0)
    x = batch.x_init * torch.tensor([stretch, 1.0, stretch], dtype=torch.float64)
    x = x + 2e-3 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    return batch, x


def _samples(x, cloth):
    """The vertices, then the face centroids (an independent twin of `contact.contact_samples`)."""
    return torch.cat([x, x[cloth.faces].mean(1)])


def _planes(batch, x):
    """Closest points and normals of the body at the vertices and face centroids of x."""
    index = torch.cat([batch.body_index, batch.body_index[batch.cloth.faces[:, 0]]])
    q = batch.bodies.query(_samples(x, batch.cloth), body_index=index)
    return q.closest, q.normal


def _potential(x, cloth, f_hat, planes=None, margin=2e-3, k_c=2.5e3):
    """Φ per garment: E_strain + E_bend + E_grav (+ E_coll on held planes at the vertices and
    face centroids) − f̂·x."""
    phi = internal_energy(x, cloth) - cloth.sum_per_garment((f_hat * x).sum(-1), cloth.vert_garment)
    if planes is not None:
        owner = torch.cat([cloth.vert_garment, cloth.face_garment])
        depth = (margin - ((_samples(x, cloth) - planes[0]) * planes[1]).sum(-1)).clamp_min(0.0)
        phi = phi + cloth.sum_per_garment(k_c * depth**3, owner)
    return phi


def _solver(kind="two_level", **kwargs):
    return StretchingSolver(kind=kind, margin=2e-3, contact_stiffness=2.5e3, **kwargs)


@pytest.mark.parametrize("inner", [1, 3], ids=["preconditioned", "truncated_newton"])
@pytest.mark.parametrize("with_body", [False, True])
def test_steps_never_raise_any_garments_potential(with_body, inner):
    batch, x0 = _case(radii=(0.16, 0.185))  # the middle rings of both tubes start inside their bodies
    gen = torch.Generator().manual_seed(1)
    f_hat = 0.02 * torch.randn(x0.shape, generator=gen, dtype=torch.float64) * batch.cloth.mass[:, None] * 9.81
    steps = 12
    # planes held for the whole solve (requery_every = steps), so Φ is one function throughout
    solver = _solver(eta=1.0, gamma=0.98, max_step=0.01, requery_every=steps, inner_steps=4, inner_iterations=inner)
    bodies = dict(bodies=batch.bodies, body_index=batch.body_index) if with_body else {}
    trace = []
    with torch.no_grad():
        solver(x0, batch.cloth, f_hat=f_hat, steps=steps, trace=trace, **bodies)
    planes = None
    if with_body:
        planes = _planes(batch, x0)
        depth = 2e-3 - ((_samples(x0, batch.cloth) - planes[0]) * planes[1]).sum(-1)
        assert (depth > 0).sum() > 10  # contact is active: the test is not vacuous
    phis = torch.stack([_potential(x, batch.cloth, f_hat, planes) for x in [x0, *trace]])  # (T + 1, G)
    assert (phis[1:] <= phis[:-1]).all()
    assert (phis[-1] < phis[0] - 0.3 * (phis[0] - phis.min(0).values.min())).all()  # it moved every garment


def test_two_level_relaxes_far_more_than_explicit_steps():
    """Without gravity the minimum is the rest shape (E = 0): 15 two-level steps remove almost
    all of a stretch, for a stiff and a soft fabric alike; 15 explicit steps at the scalar η that
    is stable for the stiff one leave much of it."""
    leather = Material(mu=6e4, lam=9e4, k_bend=1e-3, density=0.6, gravity=0.0)
    silk = Material(mu=1.6e4, lam=2e4, k_bend=2e-6, density=0.05, gravity=0.0)
    batch, x0 = _case(materials=[leather, silk])
    start = internal_energy(x0, batch.cloth)
    assert (start > 1e-3).all()
    left = {}
    for kind, eta in (("explicit", 1e-3), ("two_level", 1.0)):
        solver = _solver(kind, eta=eta, gamma=0.98, max_step=0.01)
        with torch.no_grad():
            x = solver(x0, batch.cloth, f_hat=None, steps=15)
        left[kind] = internal_energy(x, batch.cloth) / start  # share of the energy left, per garment
    assert (left["two_level"] < 0.02).all(), left
    assert (left["explicit"] > 0.2).all(), left


@pytest.mark.parametrize("kind,follow", [("explicit", False), ("two_level", False), ("two_level", True)])
def test_gradients_reach_eta_gamma_and_f_hat(kind, follow):
    batch, x0 = _case()
    solver = _solver(kind, eta=0.7 if kind == "two_level" else 1e-3, gamma=0.9, max_step=0.01, requery_every=3,
                     follow_planes=follow)
    f_hat = torch.zeros_like(x0, requires_grad=True)
    x = solver(x0, batch.cloth, f_hat=f_hat, steps=3, bodies=batch.bodies, body_index=batch.body_index)
    internal_energy(x, batch.cloth).sum().backward()
    assert solver.log_eta.grad.abs() > 0 and solver.gamma_logit.grad.abs() > 0
    assert f_hat.grad.abs().sum() > 0


@pytest.mark.parametrize("kind", ["explicit", "two_level"])
def test_packed_batch_equals_garments_alone(kind):
    """Each garment's step length (and conjugation, coarse factor) is its own: packing garments
    together changes nothing."""
    batch, x0 = _case(materials=[Material(), SILK])
    solver = _solver(kind, eta=1.0 if kind == "two_level" else 1e-3, gamma=0.98, max_step=0.01)
    with torch.no_grad():
        together = solver(x0, batch.cloth, f_hat=None, steps=10, bodies=batch.bodies, body_index=batch.body_index)
    radii, materials = [0.15, 0.13], [Material(), SILK]
    for g, (start, out) in enumerate(zip(batch.garments.split(x0), batch.garments.split(together))):
        one = make_input([_tubes()[g]], radii[g:g + 1], materials[g:g + 1], dtype=torch.float64)
        with torch.no_grad():
            alone = solver(start, one.cloth, f_hat=None, steps=10, bodies=one.bodies, body_index=one.body_index)
        torch.testing.assert_close(out, alone, rtol=1e-9, atol=1e-12)


def test_solver_kind_is_checked():
    with pytest.raises(ValueError, match="is not a valid SolverKind"):
        _solver("jacobi", eta=1.0)
    assert _solver("two_level", eta=1.0).kind is SolverKind.TWO_LEVEL
    with pytest.raises(ValueError, match="requery_every"):
        _solver(eta=1.0, requery_every=0)


def test_two_level_arguments_are_checked():
    with pytest.raises(ValueError, match="coarse_levels"):
        _solver(eta=1.0, coarse_levels=0)
    with pytest.raises(ValueError, match="contact_band"):
        _solver(eta=1.0, contact_band=-1.0)


def test_coarse_space_is_refactored_at_the_first_steps_then_every_refactor_every_steps(monkeypatch):
    batch, x0 = _case()
    calls = []
    original = CoarseSpace.factor
    monkeypatch.setattr(CoarseSpace, "factor", lambda self, *a, **k: (calls.append(1), original(self, *a, **k))[1])
    # steps 0..6: every step; at 0, 3, 6; at 0; at 0, 1, 2 and then 3, 6; at 0 and 1
    for every, first, expected in ((1, 0, 7), (3, 0, 3), (7, 0, 1), (3, 3, 5), (7, 2, 2)):
        calls.clear()
        with torch.no_grad():
            _solver(eta=1.0, gamma=0.98, max_step=0.02, requery_every=3, refactor_every=every, refactor_first=first)(
                x0, batch.cloth, f_hat=None, steps=7, bodies=batch.bodies, body_index=batch.body_index)
        assert len(calls) == expected, (every, first, len(calls))
    with pytest.raises(ValueError, match="refactor_every"):
        _solver(eta=1.0, refactor_every=0)
    with pytest.raises(ValueError, match="refactor_first"):
        _solver(eta=1.0, refactor_first=-1)
    with pytest.raises(ValueError, match="eval_requery_every"):
        _solver(eta=1.0, eval_requery_every=0)


@pytest.mark.parametrize("kind", ["two_level", "explicit"])
def test_f_hat_steps_carry_f_hat_through_the_first_steps_only(kind):
    """f_hat_steps = k: the first k steps run with f̂, the later ones without it. k = 0 is the
    solve without f̂, k ≥ T the solve with f̂ at every step (None); after step k every
    two-level step lowers the garment's own Φ (no −f̂·x term)."""
    batch, x0 = _case(radii=(0.16, 0.185))
    gen = torch.Generator().manual_seed(2)
    f_hat = 0.05 * torch.randn(x0.shape, generator=gen, dtype=torch.float64) * batch.cloth.mass[:, None] * 9.81
    eta = 1.0 if kind == "two_level" else 1e-4
    bodies = {"bodies": batch.bodies, "body_index": batch.body_index}

    def run(k, steps, f=f_hat, trace=None, **kwargs):
        solver = _solver(kind, eta=eta, gamma=0.98, max_step=0.01, requery_every=2, f_hat_steps=k)
        with torch.no_grad():
            return solver(x0, batch.cloth, f_hat=f, steps=steps, trace=trace, **kwargs)

    assert torch.equal(run(0, 6, **bodies), run(None, 6, f=None, **bodies))
    assert torch.equal(run(6, 6, **bodies), run(None, 6, **bodies))
    assert torch.equal(run(3, 3, **bodies), run(None, 3, **bodies))
    assert (run(3, 6, **bodies) - run(None, 6, **bodies)).abs().max() > 1e-9  # f̂ left out of steps 4 to 6
    if kind == "two_level":  # without a body Φ is one function: each step after the third lowers it
        trace = []
        run(3, 8, trace=trace)
        zero = torch.zeros_like(x0)
        for before, after in itertools.pairwise(trace[2:]):
            assert (_potential(after, batch.cloth, zero) <= _potential(before, batch.cloth, zero)).all()
    with pytest.raises(ValueError, match="f_hat_steps"):
        _solver(kind, eta=eta, f_hat_steps=-1)


def test_eval_mode_runs_its_own_plane_schedule(monkeypatch):
    """requery_every / follow_planes hold in training, eval_requery_every / eval_follow_planes in
    eval mode (None: as in training); the same module switches with train() / eval()."""

    batch, x0 = _case(radii=(0.16, 0.185))
    calls, original = [], relaxation.Relaxation.requery

    def requery(self, x, bodies, body_index, **kwargs):
        calls.append(kwargs.get("local", False))
        return original(self, x, bodies, body_index, **kwargs)

    monkeypatch.setattr(relaxation.Relaxation, "requery", requery)

    def schedule(solver):
        calls.clear()
        with torch.no_grad():
            solver(x0, batch.cloth, f_hat=None, steps=6, bodies=batch.bodies, body_index=batch.body_index)
        return list(calls)

    solver = _solver(eta=1.0, gamma=0.98, max_step=0.01, requery_every=3, eval_requery_every=4, eval_follow_planes=True)
    assert solver.planes_schedule() == (3, False) and schedule(solver) == [False, False]
    solver.eval()
    assert solver.planes_schedule() == (4, True) and schedule(solver) == [False, True, True, True, False, True]
    solver.train()
    assert schedule(solver) == [False, False]
    same = _solver(eta=1.0, requery_every=2, follow_planes=True).eval()
    assert same.planes_schedule() == (2, True)


def test_followed_planes_are_the_closest_point_planes_at_every_step(monkeypatch):
    """With follow_planes the samples within the contact band of their planes get, at every
    step, the planes of a body query at that step's positions (found by the local walk from the
    last step's faces); the others keep theirs. Each step still lowers Φ on the planes it holds."""

    batch, x0 = _case(radii=(0.16, 0.185))
    held, original = [], relaxation.Relaxation.requery

    def copied(planes):  # the followed planes move in place: the state of each step kept
        return None if planes is None else tuple(p.clone() for p in planes)

    def requery(self, x, bodies, body_index, **kwargs):
        before = copied(self.planes)
        change = original(self, x, bodies, body_index, **kwargs)
        held.append((kwargs.get("local", False), x.detach().clone(), before, copied(self.planes)))
        return change

    monkeypatch.setattr(relaxation.Relaxation, "requery", requery)
    band = 0.01
    solver = _solver(eta=1.0, gamma=0.98, max_step=0.01, requery_every=4, follow_planes=True, contact_band=band)
    trace = []
    with torch.no_grad():
        solver(x0, batch.cloth, f_hat=None, steps=9, trace=trace, bodies=batch.bodies, body_index=batch.body_index)
    assert [local for local, *_ in held] == [False, True, True, True, False, True, True, True, False]
    followed = kept = 0
    for local, x, before, (closest, normal) in held:  # the BVH picks faces by float32 distances: near-ties within 1e-6 m
        samples = _samples(x, batch.cloth)
        near = torch.ones(len(samples), dtype=torch.bool)
        if local:
            near = ((samples - before[0]) * before[1]).sum(-1) < band
            assert torch.equal(closest[~near], before[0][~near]) and torch.equal(normal[~near], before[1][~near])
            followed, kept = followed + int(near.sum()), kept + int((~near).sum())
        want_closest, want_normal = _planes(batch, x)
        torch.testing.assert_close((samples - closest).norm(dim=-1)[near], (samples - want_closest).norm(dim=-1)[near],
                                   atol=1e-6, rtol=0)
        torch.testing.assert_close(closest[near], want_closest[near], atol=1e-5, rtol=0)
        torch.testing.assert_close(normal[near], want_normal[near], atol=1e-3, rtol=0)
    assert followed > 1000 and kept > 100  # both kinds of samples occur
    zero = torch.zeros_like(x0)
    for (*_, planes), before, after in zip(held, [x0, *trace], trace):
        assert (_potential(after, batch.cloth, zero, planes) <= _potential(before, batch.cloth, zero, planes)).all()


def test_followed_planes_change_phi_by_the_followed_samples_penalties():
    """A local requery returns the change of Φ at x that its new planes make (the solver adds it
    to the Φ it held instead of evaluating Φ anew); a full requery returns None."""
    batch, x0 = _case(radii=(0.16, 0.185))
    f_hat = torch.zeros_like(x0)
    solver = _solver(eta=1.0)
    problem = solver._relaxation(batch.cloth, None, solver.contact_band)
    assert problem.requery(x0, batch.bodies, batch.body_index) is None
    gen = torch.Generator().manual_seed(2)
    changes = []
    for scale in (3e-3, 6e-3):  # small moves, then the samples slide farther over the body
        x = x0 + scale * torch.randn(x0.shape, generator=gen, dtype=torch.float64)
        before = problem.potential(x)
        torch.testing.assert_close(before, _potential(x, batch.cloth, f_hat, problem.planes), rtol=1e-12, atol=0)
        change = problem.requery(x, batch.bodies, batch.body_index, local=True)
        torch.testing.assert_close(before + change, _potential(x, batch.cloth, f_hat, problem.planes),
                                   rtol=1e-12, atol=1e-15)
        torch.testing.assert_close(before + change, problem.potential(x), rtol=1e-12, atol=1e-15)
        changes.append(change)
    assert all(bool((c != 0).any()) for c in changes)  # the followed planes moved some penalties


def test_followed_planes_are_found_again_only_for_samples_that_moved_min_move():
    """With follow_min_move, a local requery finds again the planes of the samples within the
    band of their planes that moved more than follow_min_move since their planes were found (at
    the closest-point planes of that step); the others keep theirs."""
    import physdrape.model.stretching_solver as module

    batch, x0 = _case(radii=(0.16, 0.185))
    band, min_move = 0.01, 1.5e-3
    solver = _solver(eta=1.0, gamma=0.98, max_step=0.01, requery_every=6, follow_planes=True, contact_band=band,
                     follow_min_move=min_move)
    problem = solver._relaxation(batch.cloth, None, solver.contact_band)
    problem.requery(x0, batch.bodies, batch.body_index)
    found_at = _samples(x0, batch.cloth)
    gen = torch.Generator().manual_seed(3)
    refound = kept_near = 0
    x = x0
    for _ in range(4):  # moves of about a millimetre: some samples pass min_move, some not yet
        x = x + 1e-3 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
        before = problem.planes
        phi = problem.potential(x)
        change = problem.requery(x, batch.bodies, batch.body_index, local=True)
        samples = _samples(x, batch.cloth)
        near = ((samples - before[0]) * before[1]).sum(-1) < band
        moved = (samples - found_at).norm(dim=-1) > min_move
        again = near & moved
        closest, normal = problem.planes
        assert torch.equal(closest[~again], before[0][~again]) and torch.equal(normal[~again], before[1][~again])
        want_closest, _ = _planes(batch, x)
        torch.testing.assert_close(closest[again], want_closest[again], atol=1e-5, rtol=0)
        torch.testing.assert_close(phi + change, problem.potential(x), rtol=1e-12, atol=1e-15)
        found_at = torch.where(again[:, None], samples, found_at)
        refound, kept_near = refound + int(again.sum()), kept_near + int((near & ~moved).sum())
    assert refound > 100 and kept_near > 100  # both kinds occur
    assert module.StretchingSolver(kind="two_level", eta=1.0, margin=2e-3, contact_stiffness=1.0).follow_min_move == 0.0
    with pytest.raises(ValueError, match="follow_min_move"):
        _solver(eta=1.0, follow_min_move=-1.0)


def _inner_problem():
    """The tubes' cloth, a factored coarse space (its K) and the two-level preconditioner C at x."""
    from functools import partial

    import physdrape.model.stretching_solver as module

    batch, x = _case()
    cloth = batch.cloth
    gen = torch.Generator().manual_seed(5)  # contact-like blocks k n nᵀ: they pin the rigid motions
    normal = torch.nn.functional.normalize(torch.randn(cloth.num_verts, 3, generator=gen, dtype=torch.float64), dim=-1)
    contact = 40.0 * torch.rand(cloth.num_verts, 1, 1, generator=gen, dtype=torch.float64) * normal[:, :, None] * normal[:, None]
    coarse = CoarseSpace(cloth)
    coarse.factor(x, contact)
    inverse = vertex_compliance(x, cloth, contact, rel=1e-6)  # the solver's floor in float64
    precondition = partial(module._precondition, inverse, coarse)

    def per_garment(values):
        return cloth.sum_per_garment(values.sum(-1), cloth.vert_garment)

    return module, cloth, coarse, precondition, per_garment


def test_truncated_newton_is_preconditioned_cg_on_k():
    """One iteration is C F at the quadratic model's best length along it; many solve K z = F
    garment by garment; the coefficients are not differentiated, so z is a linear map of F."""
    module, cloth, coarse, precondition, per_garment = _inner_problem()
    owner = cloth.vert_garment
    gen = torch.Generator().manual_seed(4)
    force = torch.randn(cloth.num_verts, 3, generator=gen, dtype=torch.float64)
    newton = module._truncated_newton
    one = newton(precondition, coarse.stiffness_product, force, 1, per_garment, owner)
    cf = precondition(force)
    length = per_garment(force * cf) / per_garment(cf * coarse.stiffness_product(cf))
    torch.testing.assert_close(one, length[owner, None] * cf, rtol=1e-12, atol=0)
    residuals = []
    for iterations in (3, 10, 400):
        z = newton(precondition, coarse.stiffness_product, force, iterations, per_garment, owner)
        residual = per_garment((force - coarse.stiffness_product(z)) ** 2).sqrt() / per_garment(force**2).sqrt()
        residuals.append(residual)
        assert bool((per_garment(force * z) > 0).all())  # a descent direction of every garment's model
    assert bool((residuals[1] < residuals[0]).all()) and bool((residuals[2] < 1e-8).all())
    f = force.clone().requires_grad_(True)
    v = torch.randn(cloth.num_verts, 3, generator=gen, dtype=torch.float64)
    z = newton(precondition, coarse.stiffness_product, f, 3, per_garment, owner)
    (grad,) = torch.autograd.grad((z * v).sum(), f)
    torch.testing.assert_close((grad * force).sum(), (v * z.detach()).sum(), rtol=1e-10, atol=0)  # z = L F


def test_inner_iterations_at_the_first_steps_by_mode(monkeypatch):
    """The truncated Newton direction at the first inner_steps steps, with training's
    inner_iterations or eval mode's; plain preconditioned steps after them and at 1 iteration."""
    import physdrape.model.stretching_solver as module

    batch, x0 = _case()
    calls, original = [], module._truncated_newton

    def newton(*args):
        calls.append(args[3])
        return original(*args)

    monkeypatch.setattr(module, "_truncated_newton", newton)
    solver = _solver(eta=1.0, max_step=0.01, inner_steps=2, inner_iterations=1, eval_inner_iterations=4)
    for mode, want in ((solver.train, []), (solver.eval, [4, 4])):
        mode()
        calls.clear()
        with torch.no_grad():
            solver(x0, batch.cloth, f_hat=None, steps=5, bodies=batch.bodies, body_index=batch.body_index)
        assert calls == want
    with pytest.raises(ValueError, match="inner_iterations"):
        _solver(eta=1.0, inner_iterations=0)


def test_planes_a_differentiated_force_may_keep_are_not_moved_by_the_next_followed_step():
    """The followed planes move in place between steps; where the positions carry a gradient
    (training through followed planes) each step's planes are its own, so that the backward of a
    step's contact force reads the planes that step held."""

    batch, x0 = _case(radii=(0.16, 0.185))
    gen = torch.Generator().manual_seed(3)
    problem = relaxation.Relaxation(batch.cloth, None, margin=2e-3, stiffness=2.5e3, band=0.01)
    problem.requery(x0, batch.bodies, batch.body_index)
    for grad in (True, False):
        x1 = (x0 + 3e-3 * torch.randn(x0.shape, generator=gen, dtype=x0.dtype)).requires_grad_(grad)
        problem.requery(x1, batch.bodies, batch.body_index, local=True)
        first = problem.planes
        kept = tuple(p.clone() for p in first)
        x2 = (x1.detach() + 3e-3 * torch.randn(x0.shape, generator=gen, dtype=x0.dtype)).requires_grad_(grad)
        problem.requery(x2, batch.bodies, batch.body_index, local=True)
        unmoved = all(torch.equal(a, b) for a, b in zip(first, kept))
        assert unmoved == grad  # without a gradient the planes are the follower's, moved in place


def test_the_bound_of_the_last_full_query_is_returned():
    """`bounds` receives the samples and their signed distances at the last full body query
    (step 4 of 6 with requery_every 4): a bound of the distances at the solve's end."""
    batch, x0 = _case(radii=(0.16, 0.185))
    solver = _solver(eta=1.0, gamma=0.98, max_step=0.01, requery_every=4, follow_planes=True)
    trace, bounds = [], []
    with torch.no_grad():
        x = solver(x0, batch.cloth, f_hat=None, steps=6, trace=trace, bodies=batch.bodies, body_index=batch.body_index,
                   bounds=bounds)
    [bound] = bounds
    index = torch.cat([batch.body_index, batch.body_index[batch.cloth.faces[:, 0]]])
    torch.testing.assert_close(bound.at, _samples(trace[3], batch.cloth), rtol=0, atol=1e-15)
    torch.testing.assert_close(bound.distance, batch.bodies.query(bound.at, body_index=index).signed_distance,
                               rtol=0, atol=1e-12)
    truth = batch.bodies.query(_samples(x, batch.cloth), body_index=index).signed_distance
    assert bool((bound.lower(_samples(x, batch.cloth)) <= truth + 1e-12).all())
    no_body = []
    solver(x0, batch.cloth, f_hat=None, steps=2, bounds=no_body)
    assert no_body == []


def test_eval_mode_steps_with_its_own_contact_band_and_the_step_parts_with_trainings(monkeypatch):
    """contact_band holds in training and for the first step that `step_parts` makes in every mode
    (a network's inputs, read as it was trained); eval_contact_band (None: as in training) for the
    steps in eval mode, with the training band as the reach of the vertices that moved. The band
    changes the drape where samples lie between the two bands."""

    batch, x0 = _case(radii=(0.16, 0.185))
    bands, original = [], relaxation.Relaxation.__init__

    def init(self, *args, band, reach=None, **kwargs):
        bands.append((band, reach))
        original(self, *args, band=band, reach=reach, **kwargs)

    monkeypatch.setattr(relaxation.Relaxation, "__init__", init)
    body = {"bodies": batch.bodies, "body_index": batch.body_index}

    def drape(solver):
        with torch.no_grad():
            return solver(x0, batch.cloth, f_hat=None, steps=4, **body)

    settings = {"eta": 1.0, "gamma": 0.98, "max_step": 0.01, "requery_every": 2}
    solver = _solver(contact_band=0.01, eval_contact_band=0.004, **settings)
    drape(solver)
    solver.step_parts(x0, batch.cloth, **body)
    assert bands == [(0.01, 0.01), (0.01, 0.01)]
    bands.clear()
    solver.eval()
    eval_drape = drape(solver)
    parts = solver.step_parts(x0, batch.cloth, **body)
    assert bands == [(0.004, 0.01), (0.01, 0.01)]
    assert not torch.equal(eval_drape, drape(_solver(contact_band=0.01, **settings).eval()))
    assert all(torch.equal(a, b) for a, b in zip(parts, _solver(contact_band=0.01, **settings).step_parts(
        x0, batch.cloth, **body)))
    with pytest.raises(ValueError, match="eval_contact_band"):
        _solver(eval_contact_band=-1e-3, **settings)


def test_a_step_stops_a_vertex_from_beyond_the_band_at_the_margin():
    """Relaxation.short_of_margin: a vertex farther than the band from its plane that the move
    would carry into the margin gets the move scaled to end at the margin; vertices within the
    band, moving away or staying outside the margin, and a relaxation without planes keep theirs."""
    batch, x0 = _case()
    cloth = batch.cloth
    problem = relaxation.Relaxation(cloth, None, margin=2e-3, stiffness=2.5e3, band=7e-3)
    move = torch.zeros_like(x0)
    assert torch.equal(problem.short_of_margin(move + 1.0, x0), move + 1.0)  # no planes yet
    n = x0.shape[0] + cloth.faces.shape[0]
    normal = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(n, 3).clone()
    x = x0.clone()
    height = torch.tensor([0.02, 0.02, 0.005, 0.02, 0.02], dtype=torch.float64)  # the first vertices' heights
    x[:5, 1] = height
    closest = torch.cat([x, x[cloth.faces].mean(1)]).clone()
    closest[:, 1] = 0.0  # the plane y = 0 under every sample
    problem.planes = (closest, normal)
    move[:5] = torch.tensor([[0.001, -0.03, 0.0],   # beyond the band, through the plane: stopped at the margin
                             [0.0, -0.01, 0.002],   # beyond the band, ends outside the margin: kept
                             [0.0, -0.01, 0.0],     # within the band: kept
                             [0.0, 0.01, 0.0],      # moving away: kept
                             [0.0, -0.018, 0.0]], dtype=torch.float64)  # ends exactly at the margin: kept
    out = problem.short_of_margin(move, x)
    scale = (0.02 - 2e-3) / 0.03
    assert torch.allclose(out[0], move[0] * scale)
    assert torch.allclose((x[0] + out[0])[1], torch.tensor(2e-3, dtype=torch.float64))
    assert torch.equal(out[1:], move[1:])


def test_a_vertex_that_moved_gets_the_band_block_within_the_band_plus_its_move():
    """Relaxation(reach=...): at a step after the first, a vertex beyond the band gets the depth-ε
    contact block 6 k_c ε n nᵀ while within band + its move since the last step of its plane (up
    to reach); the others' blocks are those of the band alone; the first step has none of them."""
    batch, x0 = _case(radii=(0.16, 0.185))
    band, reach, k_c, margin = 4e-3, 1e-2, 2.5e3, 2e-3
    made = {r: relaxation.Relaxation(batch.cloth, None, margin=margin, stiffness=k_c, band=band, reach=r)
            for r in (None, reach)}
    for problem in made.values():
        problem.requery(x0, batch.bodies, batch.body_index)
    first = {r: p.step_terms(x0)[1] for r, p in made.items()}
    assert torch.equal(first[None], first[reach])
    gen = torch.Generator().manual_seed(3)
    x1 = x0 + 6e-3 * torch.rand(x0.shape, generator=gen, dtype=torch.float64)
    second = {r: p.step_terms(x1)[1] for r, p in made.items()}
    closest, normal = (plane[:x0.shape[0]] for plane in made[reach].planes)
    distance = ((x1 - closest) * normal).sum(-1)
    within = (distance >= band) & (distance < (band + (x1 - x0).norm(dim=-1)).clamp(max=reach))
    assert within.any() and (~within).any()
    expected = 6.0 * k_c * margin * within[:, None, None] * normal[:, :, None] * normal[:, None, :]
    assert torch.allclose(second[reach] - second[None], expected, rtol=1e-12, atol=1e-12)


def test_the_solver_steps_keep_the_layer_pairs_within_reach_and_the_input_step_every_pair(monkeypatch):
    """Two tubes, the outer 2 cm outside the inner one, paired vertex by vertex: the pairs lie
    farther than their gap plus `LAYER_LINK_REACH` apart, so the solver's coarse factorisations
    get weight 0 for each (the coarse stiffness with it stays factorisable), with the outer tube
    shrunk onto the inner one 1; the step the network reads keeps every pair (no weights)."""
    from physdrape.physics.coarse_space import CoarseSpace

    batch = layered_tubes(0.12)
    cloth, n = batch.cloth, batch.garments.num_verts // 2
    normal = cloth.layers.normal
    seen = []
    factor = CoarseSpace.factor

    def spy(self, x, vertex_blocks=None, pair_blocks=None, link_weight=None):
        seen.append(link_weight)
        return factor(self, x, vertex_blocks, pair_blocks, link_weight=link_weight)

    monkeypatch.setattr(CoarseSpace, "factor", spy)
    solver = _solver(eta=1.0).eval()
    x = batch.x_init
    solver(x, cloth, f_hat=None, steps=2, bodies=batch.bodies, body_index=batch.body_index)
    assert seen and all(w is not None and not bool(w.any()) for w in seen)
    seen.clear()
    close = x.clone()
    close[n:] = x[:n] + 0.004 * normal  # the outer tube at its gap over the inner one
    solver(close, cloth, f_hat=None, steps=1, bodies=batch.bodies, body_index=batch.body_index)
    assert len(seen) == 1 and bool(seen[0].all())
    seen.clear()
    solver.step_parts(x, cloth, bodies=batch.bodies, body_index=batch.body_index)
    assert seen == [None]
