"""The body's normal under each vertex as network input (`ModelConfig.body_normal_inputs`)."""

import pytest
import torch
from drape_cases import make_input, tube

from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.model.features import BODY_FEATURES, NODE_FEATURES, STEP_FEATURES
from physdrape.train.loss import LossConfig, drape_loss


def _batch():
    """Two tubes around their spheres, sheared so the body's normal under a vertex differs from
    the garment's own normal there."""
    tubes = [tube(6, 16, 0.14, dtype=torch.float64, name="a"), tube(5, 13, 0.17, dtype=torch.float64, name="b")]
    batch = make_input(tubes, [0.15, 0.13], dtype=torch.float64)
    return batch


@pytest.mark.parametrize("step_inputs", [False, True])
def test_the_network_reads_the_body_normal_after_the_node_features(step_inputs):
    torch.manual_seed(0)
    batch = _batch()
    config = ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY, step_inputs=step_inputs,
                         body_normal_inputs=True)
    model = PhysDrape(config).double()
    plain = PhysDrape(ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY,
                                  step_inputs=step_inputs)).double()
    nodes, _, _ = model.graph_inputs(batch)
    without, _, _ = plain.graph_inputs(batch)
    assert nodes.shape[1] == NODE_FEATURES + BODY_FEATURES + (STEP_FEATURES if step_inputs else 0)
    # the body normal sits between the node features and the step parts, which are unchanged
    torch.testing.assert_close(nodes[:, :NODE_FEATURES], without[:, :NODE_FEATURES])
    torch.testing.assert_close(nodes[:, NODE_FEATURES + BODY_FEATURES:], without[:, NODE_FEATURES:])
    query = batch.bodies.query(batch.x_init, body_index=batch.body_index)
    normal = nodes[:, NODE_FEATURES:NODE_FEATURES + BODY_FEATURES]
    torch.testing.assert_close(normal, query.normal.to(normal.dtype))
    torch.testing.assert_close(normal.norm(dim=-1), torch.ones(len(normal), dtype=normal.dtype))
    # on a sphere the body's outward normal is the direction from its centre, not the tube's normal
    garment_normal = nodes[:, :3]
    assert float((normal - garment_normal).norm(dim=-1).max()) > 0.1


def test_the_body_normal_columns_receive_gradient():
    torch.manual_seed(0)
    batch = _batch()
    model = PhysDrape(ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY, step_inputs=True,
                                  body_normal_inputs=True)).double()
    out = model(batch)
    loss, _ = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, LossConfig(),
                         contact_stiffness=model.config.contact_stiffness, margin=model.config.margin)
    loss.backward()
    first = model.gnn.node_encoder[0].weight.grad
    assert float(first[:, NODE_FEATURES:NODE_FEATURES + BODY_FEATURES].abs().sum()) > 0
