"""The lookahead term: a pull toward where a few solver steps take the drape."""

from dataclasses import replace

import pytest
import torch

from physdrape.model import ModelConfig
from physdrape.physics.energy import total_energy
from physdrape.train.data import DataConfig, DrapeSource
from physdrape.train.loss import (
    LossConfig,
    drape_loss,
    lookahead_target,
    teacher_distance,
)
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

pytestmark = pytest.mark.anny

SMALL = ModelConfig(latent=8, blocks=3, levels=1, zero_init_output=True, variant="gnn")


def _source(tiny_split, anny_body) -> DrapeSource:
    data = DataConfig(split_dir=tiny_split, body_pool_size=2, validation_garments=1)
    return DrapeSource(data, model=SMALL, body=anny_body)


def test_lookahead_target_lowers_the_energy_and_its_gradient_is_the_mass_weighted_step(tiny_split, anny_body):
    d = _source(tiny_split, anny_body).make_batch([2]).drape
    contact = {"contact_stiffness": SMALL.contact_stiffness, "margin": SMALL.margin}
    config = LossConfig(lookahead_weight=500.0, lookahead_steps=2)
    x = d.x_init.clone().requires_grad_(True)
    target = lookahead_target(x, d.cloth, d.bodies, d.body_index, config, SMALL)
    assert not target.requires_grad
    start = total_energy(d.x_init, d.cloth, d.bodies, d.body_index, **contact)
    assert (total_energy(target, d.cloth, d.bodies, d.body_index, **contact) < start).all()
    assert float((target - d.x_init).norm(dim=-1).max()) > 1e-5  # the solver moved the drape
    loss, terms = drape_loss(x, d.cloth, d.bodies, d.body_index, config, lookahead=target, **contact)
    plain, _ = drape_loss(x, d.cloth, d.bodies, d.body_index, LossConfig(), **contact)
    torch.testing.assert_close(loss, plain + 500.0 * teacher_distance(x, target, d.cloth).mean())
    assert terms["lookahead_rms"] > 0
    # the term's gradient points each vertex along the solver's step, weighted by its mass
    (grad,) = torch.autograd.grad(500.0 * teacher_distance(x, target, d.cloth).sum(), x)
    mass = d.cloth.mass[:, None] / d.cloth.sum_per_garment(d.cloth.mass, d.cloth.vert_garment)[d.cloth.vert_garment, None]
    torch.testing.assert_close(grad, -1000.0 * mass * (target - d.x_init))
    with pytest.raises(ValueError, match="lookahead target"):
        drape_loss(x, d.cloth, d.bodies, d.body_index, config, **contact)


@pytest.mark.parametrize("bad", [{"lookahead_weight": -1.0}, {"lookahead_steps": 0}])
def test_lookahead_settings_are_checked(bad):
    with pytest.raises(ValueError, match="lookahead"):
        LossConfig(**bad)


def test_training_with_the_lookahead_lowers_the_loss(tmp_path, tiny_split, anny_body):
    config = TrainConfig(model=SMALL, loss=LossConfig(lookahead_weight=1e3, lookahead_steps=2),
                         optim=OptimConfig(steps=32, batch_size=1, lr=3e-3, checkpoint_every=32, log_every=1),
                         data=replace(DataConfig(), split_dir=tiny_split, body_pool_size=2, validation_garments=1))
    source = _source(tiny_split, anny_body)
    fixed = source.make_batch([5])
    source.make_batch = lambda seeds: fixed
    history = Trainer(config, source, tmp_path / "run", progress=False, tensorboard=False).run()
    losses = [r["loss"] for r in history]
    assert sum(losses[-3:]) < sum(losses[:3]), losses
    # the term took part in every step (its own effect on the drape is too small to show over a
    # smoke run: the distance to the solver's target moves by a fraction of a percent either way)
    rms = [r["lookahead_rms"] for r in history]
    assert all(0.0 < r < 1.0 for r in rms), rms
