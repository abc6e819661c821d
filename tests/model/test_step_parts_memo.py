"""The solver's first step at each training instance's X_init, computed once and handed to the
model with the batch (`physdrape.train.step_parts_memo`, `DrapeInput.step_parts`)."""

from dataclasses import replace

import torch
from drape_cases import make_input

from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.train.data import TrainingBatch
from physdrape.train.step_parts_memo import StepPartsMemo

MODEL = ModelConfig(latent=8, blocks=2, levels=1, variant=Variant.GNN_ONLY, step_inputs=True)


def _model(config: ModelConfig = MODEL) -> PhysDrape:
    torch.manual_seed(0)  # random weights: the network's move depends on its inputs
    return PhysDrape(config).eval()


def test_held_parts_are_the_computed_ones_per_instance_whatever_the_batch(two_tubes):
    model = _model()
    memo = StepPartsMemo(model)
    batch = make_input(two_tubes, [0.15, 0.13])
    sample = memo.attach(TrainingBatch(batch, instances=(7, 3)))
    computed = model.step_parts_at(batch)
    assert len(sample.drape.step_parts) == len(computed) == 2
    for held, made in zip(sample.drape.step_parts, computed):
        assert torch.equal(held, made)
    with torch.no_grad():  # the model's drape with the held parts is the one it makes computing them
        assert torch.equal(model(sample.drape).x_gnn, model(batch).x_gnn)
    # the same instances in another order and batch: held, not computed again, in the sample's order
    calls = []
    original = model.step_parts_at
    model.step_parts_at = lambda *args, **kwargs: calls.append(1) or original(*args, **kwargs)
    swapped = make_input(two_tubes[::-1], [0.13, 0.15])
    again = memo.attach(TrainingBatch(swapped, instances=(3, 7)))
    assert calls == []
    for held, made in zip(again.drape.step_parts, original(swapped)):
        assert torch.equal(held, made)


def test_the_model_reads_the_held_parts_and_computes_the_others(two_tubes):
    model = _model()
    batch = make_input(two_tubes, [0.15, 0.13])
    zeros = tuple(torch.zeros_like(p) for p in model.step_parts_at(batch))
    with torch.no_grad():
        plain, held_zeros = model(batch).x_gnn, model(replace(batch, step_parts=zeros)).x_gnn
    assert float((plain - held_zeros).abs().max()) > 1e-6  # other parts, another move: the check can fail
    # a sample without instance indices, or a network that does not read the parts: unchanged
    memo = StepPartsMemo(model)
    assert memo.attach(TrainingBatch(batch)).drape.step_parts is None
    plain_model = _model(replace(MODEL, step_inputs=False))
    assert StepPartsMemo(plain_model).attach(TrainingBatch(batch, instances=(1, 2))).drape.step_parts is None
