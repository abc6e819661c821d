"""Several network passes: pass k > 1 reads its inputs at the garment the passes before it moved."""

import pytest
import torch
from drape_cases import make_input

from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.train.loss import LossConfig, drape_loss

MODEL = ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY, passes=2)
CONTACT = {"contact_stiffness": MODEL.contact_stiffness, "margin": MODEL.margin}


def _pass(model: PhysDrape, batch, x: torch.Tensor) -> torch.Tensor:
    nodes, edges, graph = model.graph_inputs(batch, x)
    return model.gnn(model.node_normalizer(nodes), model.edge_normalizer(edges), graph)


def test_the_second_pass_reads_the_garment_the_first_moved(two_tubes):
    torch.manual_seed(0)
    model = PhysDrape(MODEL).eval()  # the normalisers' statistics fixed
    batch = make_input(two_tubes, [0.15, 0.13])
    out = model(batch)
    scale = MODEL.displacement_scale
    first = batch.x_init + scale * _pass(model, batch, batch.x_init)[:, :3]
    last = _pass(model, batch, first)
    torch.testing.assert_close(out.x_gnn, first + scale * last[:, :3], rtol=1e-5, atol=1e-8)
    weight = batch.cloth.mass * batch.cloth.gravity[batch.cloth.vert_garment].norm(dim=-1)
    torch.testing.assert_close(out.f_hat, last[:, 3:] * weight[:, None], rtol=1e-5, atol=1e-10)
    # not one pass twice as long: the second pass's inputs differ from the first's
    assert float((last - _pass(model, batch, batch.x_init)).detach().abs().max()) > 1e-6
    # the first pass's drape is kept for a loss on it
    assert len(out.earlier_passes) == 1
    torch.testing.assert_close(out.earlier_passes[0], first, rtol=1e-5, atol=1e-8)


def test_one_pass_is_the_plain_network(two_tubes):
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(**{**MODEL.__dict__, "passes": 1})).eval()
    batch = make_input(two_tubes, [0.15, 0.13])
    expected = batch.x_init + MODEL.displacement_scale * _pass(model, batch, batch.x_init)[:, :3]
    out = model(batch)
    torch.testing.assert_close(out.x_gnn, expected, rtol=1e-6, atol=1e-9)
    assert out.earlier_passes == ()


def test_the_loss_on_each_pass_adds_the_earlier_passes_energies(two_tubes):
    torch.manual_seed(0)
    model = PhysDrape(MODEL).eval()
    batch = make_input(two_tubes, [0.15, 0.13])
    out = model(batch)
    args = (batch.cloth, batch.bodies, batch.body_index)
    plain, _ = drape_loss(out.x, *args, LossConfig(), **CONTACT)
    first, _ = drape_loss(out.earlier_passes[0], *args, LossConfig(), **CONTACT)
    each, logged = drape_loss(out.x, *args, LossConfig(earlier_passes_weight=0.5), earlier_passes=out.earlier_passes,
                              **CONTACT)
    torch.testing.assert_close(each, plain + 0.5 * first)
    torch.testing.assert_close(logged["earlier_passes"], first)
    assert float((first - plain).abs()) > 1e-6  # the passes' drapes differ: the check can fail
    # without the earlier drapes (one pass) the term adds nothing
    alone, _ = drape_loss(out.x, *args, LossConfig(earlier_passes_weight=0.5), **CONTACT)
    torch.testing.assert_close(alone, plain)
    with pytest.raises(ValueError, match="earlier_passes_weight"):
        LossConfig(earlier_passes_weight=-1.0)


def test_training_two_passes_lowers_the_energy(two_tubes):
    """A smoke run: GNN-only with two passes, Adam on the paper's energy loss, one batch; the
    gradient reaches every parameter."""
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(**{**MODEL.__dict__, "zero_init_output": True}))
    batch = make_input(two_tubes, [0.15, 0.13])
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for step in range(30):
        loss, _ = drape_loss(model(batch).x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
        optimizer.zero_grad()
        loss.backward()
        if step == 1:  # the decoder's zero start has let the gradient through by now
            missing = [n for n, p in model.gnn.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
            assert missing == [], f"no gradient reaches {missing}"
        optimizer.step()
        losses.append(float(loss))
    assert losses[-1] < 0.95 * losses[0] and losses[-1] < min(losses[:10]), losses


def test_passes_must_be_positive():
    with pytest.raises(ValueError, match="passes"):
        ModelConfig(passes=0)


def test_in_eval_mode_the_solver_starts_from_the_extrapolated_move(two_tubes):
    """ModelConfig.eval_move_gain g: with the solver (no steps, no handler: its start is the
    drape) the start is X_init + g Δx in eval mode and the network's drape in training; the
    output's x_gnn is the network's drape either way, and GNN only ignores g."""
    torch.manual_seed(0)
    config = ModelConfig(**{**MODEL.__dict__, "passes": 1, "variant": Variant.GNN_SOLVER, "eval_move_gain": 1.5})
    model = PhysDrape(config).eval()
    batch = make_input(two_tubes, [0.15, 0.13])
    out = model(batch, steps=0)
    move = out.x_gnn - batch.x_init
    assert float(move.abs().max()) > 1e-6  # the network moves the garment: the check can fail
    torch.testing.assert_close(out.x, batch.x_init + 1.5 * move)
    gnn = PhysDrape(ModelConfig(**{**config.__dict__, "variant": Variant.GNN_ONLY})).eval()
    gnn.load_state_dict(model.state_dict())
    torch.testing.assert_close(gnn(batch).x, out.x_gnn)
    trained = model.train()(batch, steps=0)  # (training also moves the normalisers' statistics)
    torch.testing.assert_close(trained.x, trained.x_gnn)
    with pytest.raises(ValueError, match="eval_move_gain"):
        ModelConfig(eval_move_gain=0.0)
