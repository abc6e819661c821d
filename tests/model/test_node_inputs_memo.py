"""The network's inputs at each training instance's X_init, computed once and handed to the
model with the batch (`physdrape.train.node_inputs_memo`, `DrapeInput.x_init_nodes`)."""

from dataclasses import replace

import pytest
import torch
from drape_cases import make_input

from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.train.data import TrainingBatch
from physdrape.train.node_inputs_memo import NodeInputsMemo

MODEL = ModelConfig(latent=8, blocks=2, levels=1, variant=Variant.GNN_ONLY, step_inputs=True)


def _model(config: ModelConfig = MODEL) -> PhysDrape:
    torch.manual_seed(0)  # random weights: the network's move depends on its inputs
    return PhysDrape(config).eval()


@pytest.mark.parametrize("step_inputs", [True, False])
def test_held_inputs_are_the_computed_ones_per_instance_whatever_the_batch(two_tubes, step_inputs):
    model = _model(replace(MODEL, step_inputs=step_inputs))
    memo = NodeInputsMemo(model)
    batch = make_input(two_tubes, [0.15, 0.13])
    sample = memo.attach(TrainingBatch(batch, instances=(7, 3)))
    assert torch.equal(sample.drape.x_init_nodes, model.node_inputs(batch))
    with torch.no_grad():  # the model's drape with the held inputs is the one it makes computing them
        assert torch.equal(model(sample.drape).x_gnn, model(batch).x_gnn)
        held, made = model.graph_inputs(sample.drape), model.graph_inputs(batch)
        assert torch.equal(held[0], made[0]) and torch.equal(held[1], made[1])
    # the same instances in another order and batch: held, not computed again, in the sample's order
    calls = []
    original = model.node_inputs
    model.node_inputs = lambda *args, **kwargs: calls.append(1) or original(*args, **kwargs)
    swapped = make_input(two_tubes[::-1], [0.13, 0.15])
    again = memo.attach(TrainingBatch(swapped, instances=(3, 7)))
    assert calls == []
    assert torch.equal(again.drape.x_init_nodes, original(swapped))


def test_the_model_reads_the_held_inputs_at_x_init_only(two_tubes):
    model = _model(replace(MODEL, passes=2))
    batch = make_input(two_tubes, [0.15, 0.13])
    held = model.node_inputs(batch)
    with torch.no_grad():
        plain = model(batch).x_gnn
        assert torch.equal(model(replace(batch, x_init_nodes=held)).x_gnn, plain)  # the second pass computes its own
        other = model(replace(batch, x_init_nodes=torch.zeros_like(held))).x_gnn
    assert float((plain - other).abs().max()) > 1e-6  # other inputs, another move: the check can fail
    # a sample without instance indices: unchanged
    assert NodeInputsMemo(model).attach(TrainingBatch(batch)).drape.x_init_nodes is None
