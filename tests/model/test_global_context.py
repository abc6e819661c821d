"""The network's garment summaries (`ModelConfig.global_context`): silent until trained, one per
garment of a batch, and reaching every vertex of the garment in one block."""

import torch
from device_params import needs_compiler
from drape_cases import layered_tubes, make_input

from physdrape.config_io import to_mapping
from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.model.physdrape import summary_groups
from physdrape.train.loss import LossConfig, drape_loss

CONFIG = ModelConfig(latent=16, blocks=3, levels=1, variant=Variant.GNN_ONLY)


def _with_summaries(config: ModelConfig = CONFIG) -> PhysDrape:
    return PhysDrape(ModelConfig(**{**to_mapping(config), "global_context": True}))


def _random_summaries(model: PhysDrape) -> None:
    """Non-zero weights for the summaries' last layers and the decoder's (zero at the start)."""
    with torch.no_grad():
        for summary in model.gnn.global_mlps:
            summary[-1].weight.normal_(0.0, 0.3)
            summary[-1].bias.normal_(0.0, 0.3)
        for p in model.gnn.decoder.parameters():
            p.normal_(0.0, 0.1)


def test_summaries_start_at_zero_and_learn(two_tubes):
    """Added to a network, the summaries leave its drape as it was until trained (so they can be
    added to a trained network), and the loss's gradient reaches them."""
    torch.manual_seed(0)
    base = PhysDrape(CONFIG)
    summarised = _with_summaries()
    missing, unexpected = summarised.load_state_dict(base.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith("gnn.global_mlps.") for k in missing)
    with torch.no_grad():  # the decoder at zero would hide a difference: give it weights
        for model in (base, summarised):
            torch.manual_seed(1)
            for p in model.gnn.decoder.parameters():
                p.normal_(0.0, 0.1)
    batch = make_input(two_tubes, [0.15, 0.15])
    torch.testing.assert_close(summarised(batch).x, base(batch).x, rtol=0, atol=0)
    loss, _ = drape_loss(summarised(batch).x, batch.cloth, batch.bodies, batch.body_index, LossConfig(),
                         contact_stiffness=CONFIG.contact_stiffness, margin=CONFIG.margin)
    loss.backward()
    assert all(float(s[-1].weight.grad.abs().sum()) > 0 for s in summarised.gnn.global_mlps)


def test_each_garment_of_a_batch_is_summarised_on_its_own(two_tubes):
    """A garment's output in a batch, as one graph or garment by garment, is its output alone:
    the summaries average over the garment's own vertices (float64)."""
    torch.manual_seed(0)
    model = _with_summaries().double().eval()
    _random_summaries(model)
    batch = make_input(two_tubes, [0.15, 0.13])
    nodes, edges, graph = model.graph_inputs(batch)
    offsets = batch.garments.vert_offsets.tolist()
    garments = batch.garments.vert_garment
    whole = model.gnn(nodes.double(), edges.double(), graph, groups=garments)
    pieces = model.gnn(nodes.double(), edges.double(), graph, parts=offsets, groups=garments)
    torch.testing.assert_close(pieces, whole, rtol=1e-12, atol=1e-12)
    for k in range(2):
        alone = make_input(two_tubes[k:k + 1], [[0.15, 0.13][k]])
        n, e, g = model.graph_inputs(alone)
        torch.testing.assert_close(whole[offsets[k]:offsets[k + 1]], model.gnn(n.double(), e.double(), g),
                                   rtol=1e-10, atol=1e-12)


def test_a_summary_reaches_the_whole_garment_in_one_block(two_tubes):
    """With one block on the mesh, a vertex's output depends on its ring of neighbours only; with
    the summaries, on every vertex of its garment, and on no vertex of another garment."""
    one_block = ModelConfig(latent=8, blocks=1, levels=0, variant=Variant.GNN_ONLY)
    batch = make_input(two_tubes, [0.15, 0.13])
    offsets = batch.garments.vert_offsets.tolist()
    reached = {}
    for context in (False, True):
        torch.manual_seed(0)
        model = PhysDrape(ModelConfig(**{**to_mapping(one_block), "global_context": context})).double()
        if context:
            _random_summaries(model)
        else:
            with torch.no_grad():
                for p in model.gnn.decoder.parameters():
                    p.normal_(0.0, 0.1)
        nodes, edges, graph = model.graph_inputs(batch)
        nodes = nodes.double().requires_grad_(True)
        out = model.gnn(nodes, edges.double(), graph, groups=batch.garments.vert_garment)
        (grad,) = torch.autograd.grad(out[0].sum(), nodes)
        reached[context] = grad.abs().sum(-1) > 0
    first = slice(offsets[0], offsets[1])
    assert int(reached[False][first].sum()) < 10  # vertex 0 and its ring
    assert bool(reached[True][first].all())
    assert not bool(reached[True][offsets[1]:].any())


def test_a_multi_piece_garment_is_summarised_piece_by_piece():
    """A garment whose layer order knows its pieces gets a summary per piece (`summary_groups`):
    what one piece's vertices read does not reach the other piece's output, as it does with one
    summary for the garment (float64)."""
    from dataclasses import replace

    batch = layered_tubes(0.15)
    n = batch.garments.num_verts // 2  # the inner tube, then the outer one
    piece = torch.cat([torch.zeros(n, dtype=torch.int64), torch.ones(n, dtype=torch.int64)])
    batch = replace(batch, cloth=replace(batch.cloth, layers=replace(batch.cloth.layers, piece=piece)))
    groups = summary_groups(batch)
    assert len(set(groups[:n].tolist())) == 1 and len(set(groups[n:].tolist())) == 1 and groups[0] != groups[n]
    torch.manual_seed(0)
    model = _with_summaries().double().eval()
    _random_summaries(model)
    nodes, edges, graph = model.graph_inputs(batch)
    nodes, edges = nodes.double(), edges.double()
    moved = nodes.clone()
    moved[n:] += 1.0  # the outer piece reads other inputs
    for grouping, apart in ((groups, True), (batch.garments.vert_garment, False)):
        inner = model.gnn(nodes, edges, graph, groups=grouping)[:n]
        inner_moved = model.gnn(moved, edges, graph, groups=grouping)[:n]
        assert torch.equal(inner, inner_moved) == apart


@needs_compiler
def test_compiled_summaries_compute_what_the_eager_ones_do(two_tubes):
    """`compile_network` with the summaries: the eager output, whole and garment by garment, up to
    the rounding of fused float operations."""
    torch.manual_seed(0)
    model = _with_summaries(ModelConfig(latent=8, blocks=3, levels=1, variant=Variant.GNN_ONLY)).eval()
    _random_summaries(model)
    batch = make_input(two_tubes, [0.15, 0.13])
    nodes, edges, graph = model.graph_inputs(batch)
    offsets, garments = batch.garments.vert_offsets.tolist(), batch.garments.vert_garment

    def run():
        with torch.no_grad():
            return [model.gnn(nodes, edges, graph, groups=garments),
                    model.gnn(nodes, edges, graph, parts=offsets, groups=garments)]

    eager = run()
    model.gnn.compile_network()
    for got, want in zip(run(), eager):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5)
