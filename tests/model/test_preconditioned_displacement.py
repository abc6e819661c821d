"""The preconditioned displacement: the network's move is a force field through the two-level
solver's preconditioner C at X_init."""

import pytest
import torch
from drape_cases import make_input

from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.model.stretching_solver import StretchingSolver, clip_moves
from physdrape.physics.energy import total_energy
from physdrape.physics.forces import internal_forces
from physdrape.train.loss import LossConfig, drape_loss

MODEL = ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY, displacement="preconditioned")
CONTACT = {"contact_stiffness": MODEL.contact_stiffness, "margin": MODEL.margin}


def _solver() -> StretchingSolver:
    return StretchingSolver(kind="two_level", eta=1.0, margin=MODEL.margin, contact_stiffness=MODEL.contact_stiffness)


def _stretched(two_tubes, dtype):
    """Two tubes on their spheres, stretched 3 % along the axis and sheared: F ≠ 0, contact active."""
    batch = make_input(two_tubes, [0.15, 0.13], dtype=dtype)
    x = batch.x_init.to(dtype) * torch.tensor([1.0, 1.03, 1.0], dtype=dtype)
    x = x + 0.01 * torch.sin(7.0 * x[:, 1:2]) * torch.tensor([1.0, 0.0, 0.0], dtype=dtype)
    cloth = batch.cloth.to(dtype=dtype)
    return batch, x, cloth


def test_the_preconditioner_is_linear_symmetric_and_positive_definite(two_tubes):
    batch, x, cloth = _stretched(two_tubes, torch.float64)
    precondition = _solver().preconditioner(x, cloth, bodies=batch.bodies, body_index=batch.body_index)
    g = torch.Generator().manual_seed(0)
    u, v = (torch.randn(x.shape, generator=g, dtype=torch.float64) for _ in range(2))
    torch.testing.assert_close(precondition(2.0 * u - v), 2.0 * precondition(u) - precondition(v), rtol=1e-10, atol=0)
    torch.testing.assert_close((u * precondition(v)).sum(), (v * precondition(u)).sum(), rtol=1e-9, atol=0)
    for w in (u, v, internal_forces(x, cloth)):
        assert float((w * precondition(w)).sum()) > 0


def test_the_preconditioned_force_is_a_descent_direction_of_the_energy(two_tubes):
    batch, x, cloth = _stretched(two_tubes, torch.float64)
    precondition = _solver().preconditioner(x, cloth, bodies=batch.bodies, body_index=batch.body_index)
    move = precondition(internal_forces(x, cloth))
    energy = [total_energy(x + a * move, cloth, batch.bodies, batch.body_index, **CONTACT) for a in (0.0, 0.1)]
    assert bool((energy[1] < energy[0]).all()), energy


def test_the_explicit_solver_has_no_preconditioner():
    with pytest.raises(ValueError, match="two_level"):
        ModelConfig(displacement="preconditioned", solver="explicit")
    with pytest.raises(ValueError, match="two_level"):
        StretchingSolver(kind="explicit", eta=1e-3, margin=MODEL.margin,
                         contact_stiffness=MODEL.contact_stiffness).preconditioner(torch.zeros(3, 3), None)


def test_the_networks_move_is_its_force_through_the_preconditioner(two_tubes):
    """Δx = C (force_scale · output · m g), and the loss's gradient reaches every parameter."""
    torch.manual_seed(0)
    config = ModelConfig(**{**MODEL.__dict__, "force_scale": 3.0})
    model = PhysDrape(config)
    batch = make_input(two_tubes, [0.15, 0.13])
    out = model(batch)
    nodes, edges, graph = model.graph_inputs(batch)
    raw = model.gnn(model.node_normalizer(nodes), model.edge_normalizer(edges), graph)
    weight = batch.cloth.mass * batch.cloth.gravity[batch.cloth.vert_garment].norm(dim=-1)
    precondition = model.solver.preconditioner(batch.x_init, batch.cloth, bodies=batch.bodies,
                                               body_index=batch.body_index)
    expected = batch.x_init + clip_moves(precondition(3.0 * raw[:, :3] * weight[:, None]), config.max_move)
    torch.testing.assert_close(out.x_gnn, expected, rtol=1e-5, atol=1e-8)
    assert float((out.x_gnn - batch.x_init).detach().norm(dim=-1).max()) > 1e-6
    loss, _ = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
    loss.backward()
    missing = [n for n, p in model.gnn.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == [], f"no gradient reaches {missing}"


def test_training_through_the_preconditioner_lowers_the_energy(two_tubes):
    """A smoke run: GNN-only with the preconditioned move, Adam on the paper's energy loss, one batch."""
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(**{**MODEL.__dict__, "zero_init_output": True}))
    batch = make_input(two_tubes, [0.15, 0.13])
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        out = model(batch)
        loss, _ = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        losses.append(float(loss))
    assert losses[-1] < 0.95 * losses[0] and losses[-1] < min(losses[:10]), losses
