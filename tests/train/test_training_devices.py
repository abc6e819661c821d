"""Training on every available device: the trainer moves the model and each batch there."""

from __future__ import annotations

import math

import pytest
import torch
from device_params import DEVICES

from physdrape import checkpoint as ckpt
from physdrape.model import ModelConfig
from physdrape.train.synthetic import SyntheticSource
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

TWO_STEPS = TrainConfig(
    model=ModelConfig(latent=8, blocks=2, normalizer_accumulations=2, solver="two_level", eta=1.0, gamma=0.98,
                      max_step=0.01, requery_every=2, centroid_margin=5e-3),
    optim=OptimConfig(steps=2, batch_size=2, lr=3e-3, checkpoint_every=2, log_every=1, seed=5),
)


def _trainer(run_dir, device=None) -> Trainer:
    kwargs = {} if device is None else {"device": device}
    return Trainer(TWO_STEPS, SyntheticSource(), run_dir, progress=False, tensorboard=False, **kwargs)


@pytest.mark.parametrize("device", DEVICES)
def test_two_training_steps_on_device(tmp_path, device):
    trainer = _trainer(tmp_path / device, device)
    assert trainer.device.type == device
    assert {t.device.type for t in trainer.model.state_dict().values()} == {device}
    history = trainer.run()
    assert [r["step"] for r in history] == [1, 2]
    assert all(math.isfinite(r["loss"]) and math.isfinite(r["grad_norm"]) for r in history)
    assert {t.device.type for t in trainer.model.state_dict().values()} == {device}
    weights, _ = ckpt.read_checkpoint(tmp_path / device)  # checkpoints hold CPU tensors whatever the device
    assert {t.device.type for t in weights.values()} == {"cpu"}
    resumed = _trainer(tmp_path / device, device)
    resumed.load(ckpt.latest_checkpoint(tmp_path / device))
    for name, value in trainer.model.state_dict().items():
        assert torch.equal(resumed.model.state_dict()[name], value), name
    reference = _trainer(tmp_path / "reference").run()  # the default device: the CPU
    assert history[0]["loss"] == pytest.approx(reference[0]["loss"], rel=1e-4)
    if device == "cpu":
        assert history == [{**r, "wall_s": h["wall_s"]} for r, h in zip(reference, history)]
