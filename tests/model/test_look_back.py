"""The network's look-back stage (`ModelConfig.look_back_blocks`): it reads the solver's step parts
where its first move leaves the garment and adds a second move."""

from dataclasses import replace

import pytest
import torch
from drape_cases import make_input

from physdrape import checkpoint as ckpt
from physdrape.config_io import to_mapping
from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.model.features import STEP_FEATURES
from physdrape.train.loss import LossConfig, drape_loss
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

MODEL = ModelConfig(latent=16, blocks=3, levels=1, variant=Variant.GNN_ONLY, step_inputs=True, look_back_blocks=3)
PLAIN = replace(MODEL, look_back_blocks=0)
CONTACT = {"contact_stiffness": MODEL.contact_stiffness, "margin": MODEL.margin}


def _trained_look_back(model: PhysDrape) -> None:
    """Give the look-back decoder non-zero weights (as training would), so that its move shows."""
    torch.manual_seed(1)
    for parameter in model.gnn.look_back_decoder[-1].parameters():
        parameter.data.normal_(0.0, 0.3)


def _warmed(config: ModelConfig, batch) -> PhysDrape:
    torch.manual_seed(0)
    model = PhysDrape(config)
    model.accumulate_statistics(batch)
    return model.eval()


def test_an_untrained_look_back_leaves_the_networks_drape(two_tubes):
    batch = make_input(two_tubes, [0.15, 0.13])
    plain = _warmed(PLAIN, batch)
    model = PhysDrape(MODEL).eval()
    model.load_state_dict({**model.state_dict(), **plain.state_dict()})
    with torch.no_grad():
        expected, out = plain(batch), model(batch)
    torch.testing.assert_close(out.x_gnn, expected.x_gnn)
    # the first move's drape is kept for the loss, as an earlier pass's
    assert len(out.earlier_passes) == 1
    torch.testing.assert_close(out.earlier_passes[0], expected.x_gnn)
    assert model.gnn.look_back_schedule == [0, 1, 0]


def test_the_look_back_reads_the_step_parts_where_the_first_move_leaves_the_garment(two_tubes):
    batch = make_input(two_tubes, [0.15, 0.13])
    model = _warmed(MODEL, batch)
    _trained_look_back(model)
    nodes, edges, graph, query = model._graph_inputs(batch)  # the query of X_init's samples, whose planes are held
    nodes, edges = model.node_normalizer(nodes), model.edge_normalizer(edges)

    def reader(first):
        moved = batch.x_init + MODEL.displacement_scale * first[:, :3]
        local, coarse = model.solver.step_parts(moved, batch.cloth, bodies=batch.bodies, body_index=batch.body_index,
                                                query=query)
        parts = torch.cat([local, coarse], -1)
        stats = model.node_normalizer
        return (parts - stats.mean()[-STEP_FEATURES:].float()) / stats.std()[-STEP_FEATURES:].float()

    with torch.no_grad():
        first, out = model.gnn.forward_looking_back(nodes, edges, graph, reader)
        drape = model(batch)
        torch.testing.assert_close(first, model.gnn(nodes, edges, graph))  # the blocks' output, as without the stage
    scale = MODEL.displacement_scale
    torch.testing.assert_close(drape.x_gnn, batch.x_init + scale * out[:, :3], rtol=0, atol=1e-7)
    torch.testing.assert_close(drape.earlier_passes[0], batch.x_init + scale * first[:, :3], rtol=0, atol=1e-7)
    assert float((out - first).abs().max()) > 1e-3  # the stage moves the garment: the check can fail
    # without the look-back's features the second move differs
    with torch.no_grad():
        _, blind = model.gnn.forward_looking_back(nodes, edges, graph, lambda y: torch.zeros(len(y), STEP_FEATURES))
    assert float((blind - out).abs().max()) > 1e-5


def test_pieces_processed_one_after_the_other_give_the_same_output(two_tubes):
    batch = make_input(two_tubes, [0.15, 0.13])
    model = _warmed(MODEL, batch)
    _trained_look_back(model)
    nodes, edges, graph = model.graph_inputs(batch)
    nodes, edges = model.node_normalizer(nodes), model.edge_normalizer(edges)
    features = torch.randn(len(nodes), STEP_FEATURES, generator=torch.Generator().manual_seed(2))
    offsets = batch.garments.vert_offsets.tolist()
    with torch.no_grad():
        whole = model.gnn.forward_looking_back(nodes, edges, graph, lambda y: features)
        pieces = model.gnn.forward_looking_back(nodes, edges, graph, lambda y: features, parts=offsets)
    for a, b in zip(whole, pieces):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)


def test_the_look_back_needs_its_inputs_and_an_odd_v_cycle():
    with pytest.raises(ValueError, match="odd"):
        replace(MODEL, look_back_blocks=2)
    with pytest.raises(ValueError, match="step_inputs"):
        replace(MODEL, step_inputs=False)
    with pytest.raises(ValueError, match="direct"):
        replace(MODEL, displacement="preconditioned")
    with pytest.raises(ValueError, match="no look-back stage"):
        PhysDrape(PLAIN).gnn.forward_looking_back(None, None, None, lambda y: y)


def test_a_fine_tune_adds_the_stage_to_a_checkpoint_without_it_and_lowers_the_energy(tmp_path, two_tubes):
    """init_from a network without the stage: the run starts from that network's drape, and a
    smoke run on one batch lowers the loss through the new stage."""
    batch = make_input(two_tubes, [0.15, 0.13])
    plain = _warmed(PLAIN, batch)
    ckpt.save_checkpoint(tmp_path / "start", 0, plain, {"train": {"model": to_mapping(PLAIN), "dtype": "float32"}})

    class Source:
        def make_batch(self, seeds):
            from physdrape.train.data import TrainingBatch

            return TrainingBatch(batch)

        def validation(self):
            return []

    config = TrainConfig(model=MODEL, loss=LossConfig(earlier_passes_weight=1.0),
                         optim=OptimConfig(steps=25, batch_size=1, lr=1e-3, checkpoint_every=25, log_every=1,
                                           init_from=str(tmp_path / "start")))
    trainer = Trainer(config, Source(), tmp_path / "run", progress=False, tensorboard=False)
    trainer.init_weights(tmp_path / "start")
    with torch.no_grad():
        torch.testing.assert_close(trainer.model.eval()(batch).x_gnn, plain(batch).x_gnn)
    history = Trainer(config, Source(), tmp_path / "run2", progress=False, tensorboard=False).run()
    losses = [r["loss"] for r in history]
    assert sum(losses[-3:]) < sum(losses[:3]), losses
    start, _ = drape_loss(plain(batch).x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
    assert losses[-1] < float(start.detach())
