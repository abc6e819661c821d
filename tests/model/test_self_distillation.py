"""Self-distillation: the network a fine-tune starts from, run as several passes, as the teacher of
one pass (`physdrape.train.distill`, `LossConfig.distill_weight`)."""

from dataclasses import replace

import pytest
import torch
from drape_cases import make_input

from physdrape import checkpoint as ckpt
from physdrape.config_io import to_mapping
from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.train.data import TrainingBatch
from physdrape.train.distill import PassesTeacher
from physdrape.train.loss import LossConfig, drape_loss, teacher_distance
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

MODEL = ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY)
CONTACT = {"contact_stiffness": MODEL.contact_stiffness, "margin": MODEL.margin}


def _start(tmp_path) -> tuple[PhysDrape, str]:
    """A network with random weights (its moves not zero), saved as the checkpoint a run starts from."""
    torch.manual_seed(0)
    model = PhysDrape(MODEL).eval()
    ckpt.save_checkpoint(tmp_path / "start", 0, model, {"train": {"model": to_mapping(MODEL), "dtype": "float32"}})
    return model, str(tmp_path / "start")


class _Source:
    """One fixed batch of two garments, as cached instances 7 and 3."""

    def __init__(self, batch) -> None:
        self.batch = batch

    def make_batch(self, seeds):
        return TrainingBatch(self.batch, instances=(7, 3))

    def validation(self):
        return []


def test_the_teacher_is_the_start_network_as_several_passes_held_per_instance(tmp_path, two_tubes):
    start, path = _start(tmp_path)
    batch = make_input(two_tubes, [0.15, 0.13])
    teacher = PassesTeacher(path, 2, torch.device("cpu"))
    expected = PhysDrape(ModelConfig(**{**MODEL.__dict__, "passes": 2})).eval()
    expected.load_state_dict(start.state_dict())
    with torch.no_grad():
        target, one_pass = expected(batch).x_gnn, start(batch).x_gnn
    sample = TrainingBatch(batch, instances=(7, 3))
    torch.testing.assert_close(teacher.drapes(sample), target)
    # two passes, not one: the check can fail
    assert float((target - one_pass).abs().max()) > 1e-6
    # held per instance: the network is not run again, and the instances' drapes follow the sample's order
    calls = []
    teacher.model.register_forward_hook(lambda *args: calls.append(1))
    split = int(batch.garments.vert_offsets[1])
    swapped = TrainingBatch(batch, instances=(3, 7))
    torch.testing.assert_close(teacher.drapes(swapped), torch.cat([target[split:], target[:split]]))
    assert calls == []
    # without a cache's instance indices it is recomputed
    torch.testing.assert_close(teacher.drapes(TrainingBatch(batch)), target)
    assert calls == [1]
    # node inputs the batch holds are the trained network's: the teacher makes its own
    held = replace(batch, x_init_nodes=torch.zeros(batch.x_init.shape[0], 3))
    torch.testing.assert_close(teacher.drapes(TrainingBatch(held, instances=(5, 6))), target)
    with pytest.raises(ValueError, match="passes must be ≥ 2"):
        PassesTeacher(path, 1, torch.device("cpu"))


def test_the_distill_term_adds_the_weighted_distance_to_the_teacher(two_tubes):
    batch = make_input(two_tubes, [0.15, 0.13])
    args = (batch.cloth, batch.bodies, batch.body_index)
    x = batch.x_init + 0.003
    target = batch.x_init
    plain, _ = drape_loss(x, *args, LossConfig(), **CONTACT)
    pulled, logged = drape_loss(x, *args, LossConfig(distill_weight=1e3), distill=target, **CONTACT)
    distance = teacher_distance(x, target, batch.cloth)
    torch.testing.assert_close(pulled, plain + 1e3 * distance.mean())
    torch.testing.assert_close(logged["distill_rms"], distance.mean().sqrt())
    assert float(logged["distill_rms"]) == pytest.approx(0.003 * 3**0.5, rel=1e-4)
    # with distill_levels only the smooth part of the difference is pulled
    x = batch.x_init + 0.003 * torch.randn_like(batch.x_init, generator=torch.Generator().manual_seed(0))
    plain, _ = drape_loss(x, *args, LossConfig(), **CONTACT)
    coarse, _ = drape_loss(x, *args, LossConfig(distill_weight=1e3, distill_levels=1), distill=target, **CONTACT)
    smooth = teacher_distance(x, target, batch.cloth, levels=1)
    torch.testing.assert_close(coarse, plain + 1e3 * smooth.mean())
    assert float((smooth - teacher_distance(x, target, batch.cloth)).abs().max()) > 1e-7
    with pytest.raises(ValueError, match="teacher network's drape"):
        drape_loss(x, *args, LossConfig(distill_weight=1.0), **CONTACT)
    with pytest.raises(ValueError, match="distill_passes"):
        LossConfig(distill_passes=1)
    with pytest.raises(ValueError, match="distill_levels"):
        LossConfig(distill_levels=-1)


def test_distilling_needs_the_network_it_starts_from(two_tubes, tmp_path):
    config = TrainConfig(model=MODEL, loss=LossConfig(distill_weight=1.0), optim=OptimConfig(steps=1))
    with pytest.raises(ValueError, match="init_from"):
        Trainer(config, _Source(make_input(two_tubes, [0.15, 0.13])), tmp_path / "run", progress=False,
                tensorboard=False)


def test_training_on_the_distill_term_brings_one_pass_toward_two(tmp_path, two_tubes):
    """A smoke run from the saved network: one pass, pulled hard toward its own two-pass drape."""
    _, path = _start(tmp_path)
    batch = make_input(two_tubes, [0.15, 0.13])
    config = TrainConfig(model=MODEL, loss=LossConfig(distill_weight=1e6, distill_passes=2),
                         optim=OptimConfig(steps=30, batch_size=1, lr=1e-3, checkpoint_every=30, log_every=1,
                                           init_from=path))
    history = Trainer(config, _Source(batch), tmp_path / "run", progress=False, tensorboard=False).run()
    distances = [r["distill_rms"] for r in history]
    assert distances[0] > 1e-5  # one pass and two differ at the start
    assert sum(distances[-3:]) < 0.5 * sum(distances[:3]), distances
