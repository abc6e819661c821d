"""The PhysDrape model: gradients reach every parameter, equivariance, batching, the handler."""

import pytest
import torch
from device_params import needs_compiler
from drape_cases import make_input, tube

from physdrape.config_io import ConfigError, from_mapping, to_mapping
from physdrape.geometry.garment import GarmentBatch
from physdrape.model import DrapeInput, ModelConfig, PhysDrape, Variant
from physdrape.model.gnn import ProcessorBlock, level_schedule
from physdrape.model.physdrape import network_parts
from physdrape.physics import Cloth, Material
from physdrape.physics.energy import drape_energies
from physdrape.train.loss import LossConfig, drape_loss

#: A small model with the explicit solver: its steps are exactly equivariant to vertex relabelling
#: (the two-level solver's coarse patches are picked in vertex order), and they leave the tubes
#: inside their spheres, so the handler acts and δ gets a gradient.
SMALL = ModelConfig(latent=16, blocks=2, solver="explicit", eta=1e-3, gamma=0.9, max_step=5e-3)
CONTACT = dict(contact_stiffness=SMALL.contact_stiffness, margin=SMALL.margin)


def test_gradients_reach_every_parameter(two_tubes):
    torch.manual_seed(0)
    model = PhysDrape(SMALL)
    batch = make_input(two_tubes, [0.15, 0.15])
    out = model(batch)
    assert out.x.shape == batch.x_init.shape and out.f_hat.shape == batch.x_init.shape
    loss, terms = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
    loss.backward()
    missing = [name for name, p in model.named_parameters() if p.grad is None or p.grad.abs().sum() == 0]
    assert not missing, f"no gradient reaches {missing}"
    for name in ("solver.log_eta", "solver.gamma_logit", "handler.delta_raw"):
        assert dict(model.named_parameters())[name].grad.abs() > 0


def test_gnn_is_equivariant_to_vertex_relabelling():
    torch.manual_seed(0)
    model = PhysDrape(SMALL).eval()
    garment = tube(6, 16, 0.14)
    perm = torch.randperm(garment.num_verts, generator=torch.Generator().manual_seed(1))
    inverse = torch.argsort(perm)
    from physdrape.geometry.garment import Garment

    relabelled = Garment.from_mesh(garment.rest[perm], inverse[garment.faces], dtype=torch.float32)
    # Normalisers frozen on the same statistics for both runs.
    model(make_input([garment], [0.15]))
    out = model(make_input([garment], [0.15]))
    out_r = model(make_input([relabelled], [0.15]))
    torch.testing.assert_close(out_r.x, out.x[perm], rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(out_r.f_hat, out.f_hat[perm], rtol=1e-4, atol=1e-7)


def _reach(model: PhysDrape, garment, source: int) -> int:
    """How many vertices' X_init move the network's output at vertex `source`."""
    batch = make_input([garment], [0.1])
    x_init = batch.x_init.clone().requires_grad_(True)
    out = model(DrapeInput(batch.garments, batch.cloth, x_init, batch.bodies, batch.body_index))
    (grad,) = torch.autograd.grad(out.x_gnn[source].sum() + out.f_hat[source].sum(), x_init)
    return int((grad.abs().sum(-1) > 0).sum())


def test_coarse_levels_extend_the_networks_reach():
    """At the same number of blocks, the V-cycle over 3 coarse levels reaches nearly the whole
    40-ring tube from its middle, the mesh graph alone about a quarter of it."""
    garment = tube(40, 24, 0.14)
    reach = {}
    for levels in (0, 3):
        torch.manual_seed(0)
        model = PhysDrape(ModelConfig(latent=8, blocks=7, levels=levels)).eval()
        reach[levels] = _reach(model, garment, source=20 * 24 + 5)
    assert reach[0] < 0.3 * garment.num_verts
    assert reach[3] > 0.9 * garment.num_verts


def test_level_schedule_walks_v_cycles():
    assert level_schedule(4, 0) == [0, 0, 0, 0]
    assert level_schedule(7, 3) == [0, 1, 2, 3, 2, 1, 0]
    assert level_schedule(9, 2) == [0, 1, 2, 1, 0, 1, 2, 1, 0]


def test_mesh_blocks_start_as_the_identity_and_learn(two_tubes):
    """Blocks added on the mesh after the V-cycles leave a trained network's output as it was
    until trained, and the loss's gradient reaches them."""
    torch.manual_seed(0)
    config = ModelConfig(latent=16, blocks=3, levels=1, variant=Variant.GNN_ONLY)
    base = PhysDrape(config)
    deeper = PhysDrape(ModelConfig(**{**to_mapping(config), "mesh_blocks": 2}))
    assert deeper.gnn.schedule == level_schedule(3, 1) + [0, 0]
    missing, unexpected = deeper.load_state_dict(base.state_dict(), strict=False)
    assert not unexpected and missing and all(k.startswith(("gnn.blocks.3.", "gnn.blocks.4.")) for k in missing)
    batch = make_input(two_tubes, [0.15, 0.15])
    with torch.no_grad():  # the decoder at zero would hide a difference: give it weights
        for model in (base, deeper):
            torch.manual_seed(1)
            for p in model.gnn.decoder.parameters():
                p.normal_(0.0, 0.1)
    torch.testing.assert_close(deeper(batch).x, base(batch).x, rtol=0, atol=0)
    loss, _ = drape_loss(deeper(batch).x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
    loss.backward()
    assert float(deeper.gnn.blocks[4].node_mlp[-2].weight.grad.abs().sum()) > 0
    with pytest.raises(ValueError, match="mesh_blocks"):
        ModelConfig(mesh_blocks=-1)


@pytest.mark.parametrize("mlp_layers", [1, 2, 3])
def test_processor_block_equals_the_concatenated_form(mlp_layers):
    """The block applies its MLPs' first layers to the parts of their inputs apart: the paper's
    edge_mlp([e, h_r, h_s]) and node_mlp([h, Σ e]) on concatenated inputs, in float64, values and
    gradients."""
    torch.manual_seed(0)
    block = ProcessorBlock(8, mlp_layers=mlp_layers).double()
    nodes = torch.randn(30, 8, dtype=torch.float64, requires_grad=True)
    edges = torch.randn(70, 8, dtype=torch.float64, requires_grad=True)
    edge_index = torch.randint(0, 30, (2, 70))
    sender, receiver = edge_index
    want_e = edges + block.edge_mlp(torch.cat([edges, nodes[receiver], nodes[sender]], dim=-1))
    aggregated = torch.zeros_like(nodes).index_add_(0, receiver, want_e)
    want_h = nodes + block.node_mlp(torch.cat([nodes, aggregated], dim=-1))
    got_h, got_e = block(nodes, edges, edge_index)
    torch.testing.assert_close(got_e, want_e, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(got_h, want_h, rtol=1e-12, atol=1e-12)
    weights = torch.randn(30, 8, dtype=torch.float64)
    got = torch.autograd.grad((got_h * weights).sum(), [nodes, edges, *block.parameters()])
    want = torch.autograd.grad((want_h * weights).sum(), [nodes, edges, *block.parameters()])
    for g, w in zip(got, want):
        torch.testing.assert_close(g, w, rtol=1e-10, atol=1e-12)


def test_coarse_levels_are_subsets_with_local_edges(two_tubes):
    graph = GarmentBatch.pack(two_tubes).graph_levels(3)
    assert graph.edge_counts[0] == GarmentBatch.pack(two_tubes).edge_index.shape[1]
    for level in range(1, 4):
        ids, local = graph.nodes[level], graph.local_edge_index[level]
        assert 0 < len(ids) < len(graph.nodes[level - 1])
        torch.testing.assert_close(ids[local], graph.edge_index[:, graph.level == level])
    # a batch of the same garments again reuses the levels (and their pieces); another order does not
    assert GarmentBatch.pack(two_tubes).graph_levels(3) is graph
    assert graph.part(0, two_tubes[0].num_verts) is graph.part(0, two_tubes[0].num_verts)
    swapped = GarmentBatch.pack(two_tubes[::-1]).graph_levels(3)
    assert swapped is not graph and swapped.edge_index.shape == graph.edge_index.shape
    assert GarmentBatch.pack(two_tubes).graph_levels(2) is not graph


def test_packed_batch_with_coarse_levels_equals_garments_alone(two_tubes):
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(latent=16, blocks=2, levels=2)).eval()
    together = model(make_input(two_tubes, [0.15, 0.13])).x
    a, b = GarmentBatch.pack(two_tubes).split(together)
    torch.testing.assert_close(a, model(make_input(two_tubes[:1], [0.15])).x, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(b, model(make_input(two_tubes[1:], [0.13])).x, rtol=1e-5, atol=1e-6)


def test_network_in_pieces_equals_the_whole_graph(two_tubes):
    """The network run garment by garment (`parts`) gives the batch graph's output and gradients;
    `network_parts` groups consecutive garments into pieces of at most so many vertices (float64:
    the gradients sum the garments' terms in another order)."""
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(latent=16, blocks=5, levels=2)).eval()
    batch = make_input(two_tubes, [0.15, 0.13])
    nodes, edges, graph = model.graph_inputs(batch)
    network = model.gnn.double()
    nodes, edges = nodes.double().requires_grad_(True), edges.double()
    offsets = batch.garments.vert_offsets.tolist()
    whole = network(nodes, edges, graph)
    pieces = network(nodes, edges, graph, parts=offsets)
    torch.testing.assert_close(pieces, whole, rtol=1e-12, atol=1e-12)
    weights = torch.randn_like(whole)
    got = torch.autograd.grad((pieces * weights).sum(), [nodes, *network.parameters()])
    want = torch.autograd.grad((whole * weights).sum(), [nodes, *network.parameters()])
    for g, w in zip(got, want):
        torch.testing.assert_close(g, w, rtol=1e-10, atol=1e-12)
    assert network_parts([0, 3000, 6000, 7000, 12000, 12500], most=4096) == [0, 3000, 7000, 12000, 12500]
    assert network_parts(offsets) == [0, offsets[-1]] and network_parts([0]) == [0]


@needs_compiler
def test_compiled_network_computes_what_the_eager_one_does(two_tubes):
    """`compile_network`: the network runs compiled (one compilation for every garment size and
    for a batch in pieces, one for inference and one recording gradients), with the eager output
    and gradients up to the rounding of fused float operations."""
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(latent=8, blocks=3, levels=1))
    network = model.gnn
    batch = make_input(two_tubes, [0.15, 0.13])
    nodes, edges, graph = model.graph_inputs(batch)
    offsets = batch.garments.vert_offsets.tolist()
    weights = torch.randn(nodes.shape[0], network.decoder[-1].out_features)

    def run():
        with torch.no_grad():
            outs = [network(nodes, edges, graph), network(nodes, edges, graph, parts=offsets)]
        network.zero_grad()
        (network(nodes, edges, graph, parts=offsets) * weights).sum().backward()
        return outs, [p.grad.clone() for p in network.parameters()]

    eager, eager_grads = run()
    network.compile_network()
    compiled, compiled_grads = run()
    assert network._compiled is not None and not network._compile_pending  # both modes compiled
    for got, want in zip(compiled, eager):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-5)
    for got, want in zip(compiled_grads, eager_grads):
        torch.testing.assert_close(got, want, rtol=1e-3, atol=1e-5)


def test_a_network_that_cannot_compile_runs_eagerly(two_tubes, monkeypatch):
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(latent=8, blocks=2)).eval()
    nodes, edges, graph = model.graph_inputs(make_input(two_tubes, [0.15, 0.13]))
    with torch.no_grad():
        want = model.gnn(nodes, edges, graph)

    def broken(*args, **kwargs):
        raise RuntimeError("no C++ compiler here")

    monkeypatch.setattr(torch, "compile", lambda fn, **kwargs: broken)
    model.gnn.compile_network()
    with torch.no_grad(), pytest.warns(UserWarning, match="could not compile the network.*no C\\+\\+ compiler"):
        got = model.gnn(nodes, edges, graph)
    assert torch.equal(got, want) and model.gnn._compiled is None


def test_zero_initialised_output_starts_at_x_init(two_tubes):
    model = PhysDrape(ModelConfig(latent=8, blocks=1, zero_init_output=True, variant=Variant.GNN_ONLY)).eval()
    batch = make_input(two_tubes, [0.15, 0.13])
    out = model(batch)
    assert torch.equal(out.x, batch.x_init) and not out.f_hat.any()


def test_packed_batch_equals_garments_alone(two_tubes):
    torch.manual_seed(0)
    model = PhysDrape(SMALL).eval()
    silk = Material(mu=1.6e4, lam=2e4, k_bend=2e-6, density=0.05)
    batch = make_input(two_tubes, [0.15, 0.13], [Material(), silk])
    together = model(batch).x
    alone_a = model(make_input(two_tubes[:1], [0.15], [Material()])).x
    alone_b = model(make_input(two_tubes[1:], [0.13], [silk])).x
    a, b = batch.garments.split(together)
    torch.testing.assert_close(a, alone_a, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(b, alone_b, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("variant", [Variant.FULL, Variant.GNN_COLLISION])
def test_after_the_handler_no_vertex_is_closer_than_the_margin(two_tubes, variant):
    torch.manual_seed(0)
    model = PhysDrape(ModelConfig(latent=16, blocks=2, variant=variant)).eval()
    batch = make_input(two_tubes, [0.15, 0.18])  # both tubes start partly inside their spheres
    before = batch.bodies.query(batch.x_init, body_index=batch.body_index).signed_distance
    assert (before < 0).sum() > 10
    out = model(batch)
    after = batch.bodies.query(out.x, body_index=batch.body_index)
    assert after.signed_distance.min() >= model.config.margin * (1 - 1e-4)
    assert not after.inside.any()
    faces = batch.garments.faces  # and after the (one-shot) centroid pass no face centroid is inside
    centroids = batch.bodies.query(out.x[faces].mean(dim=1), body_index=batch.body_index[faces[:, 0]])
    assert centroids.signed_distance.min() > 0 and not centroids.inside.any()


def test_variants_switch_modules(two_tubes):
    torch.manual_seed(0)
    batch = make_input(two_tubes, [0.15, 0.18])
    gnn_only = PhysDrape(ModelConfig(latent=16, blocks=2, variant=Variant.GNN_ONLY)).eval()
    out = gnn_only(batch)
    torch.testing.assert_close(out.x, out.x_gnn)
    post = PhysDrape(ModelConfig(latent=16, blocks=2, variant=Variant.POST_COL))
    post.load_state_dict(gnn_only.state_dict())
    assert post.train()(batch).x.shape == out.x.shape  # no handler in training
    post.eval()
    traced = post(batch, keep_trace=True)
    assert len(traced.trace) == post.config.eval_steps
    distance = batch.bodies.query(traced.x, body_index=batch.body_index).signed_distance
    assert distance.min() >= post.config.margin * (1 - 1e-4)


def test_config_is_strict():
    with pytest.raises(ConfigError, match=r"unknown keys \['widht'\]"):
        from_mapping(ModelConfig, {"widht": 3})
    with pytest.raises(ConfigError, match="variant: 'half' is not one of"):
        from_mapping(ModelConfig, {"variant": "half"})
    assert from_mapping(ModelConfig, to_mapping(ModelConfig.paper())) == ModelConfig.paper()


def test_per_garment_scaled_loss_divides_each_garment_by_its_start(two_tubes):
    batch = make_input(two_tubes, [0.15, 0.13], dtype=torch.float64)
    batch = DrapeInput(batch.garments.to(torch.float64), Cloth.build(batch.garments.to(torch.float64)),
                       batch.x_init.double(), batch.bodies, batch.body_index)
    x_init = batch.x_init * 1.05
    x = batch.x_init * 1.02
    plain, terms = drape_loss(x, batch.cloth, batch.bodies, batch.body_index, LossConfig(), **CONTACT)
    scaled, terms_s = drape_loss(x, batch.cloth, batch.bodies, batch.body_index,
                                 LossConfig(per_garment_scale="initial"), x_init, **CONTACT)
    energy = drape_energies(x, batch.cloth, batch.bodies, batch.body_index, **CONTACT)
    start = drape_energies(x_init, batch.cloth, batch.bodies, batch.body_index, **CONTACT)
    weight = batch.cloth.sum_per_garment(batch.cloth.mass, batch.cloth.vert_garment) * 9.81
    scale = start["strain"] + start["bend"] + start["collision"] + 0.01 * weight
    torch.testing.assert_close(scaled, (sum(energy.values()) / scale).mean())
    torch.testing.assert_close(plain, sum(energy.values()).mean())
    assert all(torch.equal(terms[k], terms_s[k]) for k in terms)  # logged terms stay in joules
    with pytest.raises(ValueError, match="x_init"):
        drape_loss(x, batch.cloth, batch.bodies, batch.body_index, LossConfig(per_garment_scale="initial"), **CONTACT)
    with pytest.raises(ValueError, match="per_garment_scale"):
        LossConfig(per_garment_scale="relative")


@pytest.mark.parametrize("solver", ["explicit", "two_level"])
def test_physics_only_is_the_model_with_a_silent_network(two_tubes, solver):
    """`physics_only` (Δx = 0, f̂ = 0) equals the full forward pass of a network whose output is zero:
    exactly at inference; to rounding where the forward pass carries gradients (its solver's forces
    then come from the differentiable per-term kernels, summed in another order)."""
    model = PhysDrape(ModelConfig(latent=8, blocks=1, zero_init_output=True, solver=solver,
                                  eta=1.0 if solver == "two_level" else 1e-3)).eval()
    batch = make_input(two_tubes, [0.15, 0.18])
    with torch.no_grad():
        full, alone = model(batch, steps=4), model.physics_only(batch, steps=4)
    assert not torch.equal(full.x, batch.x_init)  # the solver and handler moved it
    torch.testing.assert_close(alone.x, full.x, rtol=0, atol=0)
    torch.testing.assert_close(model(batch, steps=4).x.detach(), full.x, rtol=1e-5, atol=1e-6)
    torch.nn.init.normal_(model.gnn.decoder[-1].weight)  # a network that speaks changes the forward pass only
    with torch.no_grad():
        assert not torch.equal(model(batch, steps=4).x, alone.x)
        torch.testing.assert_close(model.physics_only(batch, steps=4).x, alone.x, rtol=0, atol=0)


def test_network_move_keeps_the_layer_order():
    """Where the network's move drives an outer piece into the piece under it, the outer vertex
    goes back out: the move adds nothing to a pair's layer-order shortfall over X_init's; a
    single-piece batch is left as the network moved it."""
    from dataclasses import replace

    from physdrape.geometry.garment import Garment
    from physdrape.physics.layers import LayerOrder, layer_shortfall

    inner, outer = tube(4, 12, 0.14, dtype=torch.float64), tube(4, 12, 0.16, dtype=torch.float64)
    verts = torch.cat([inner.rest, outer.rest])
    faces = torch.cat([inner.faces, outer.faces + inner.num_verts])
    garment = Garment.from_mesh(verts, faces, name="two_layers", dtype=torch.float64)
    inp = make_input([garment], [0.1], dtype=torch.float64)
    n = inner.num_verts
    pairs = torch.stack([torch.arange(n) + n, torch.arange(n)], dim=1)
    radial = inp.x_init[:n] * torch.tensor([1.0, 0.0, 1.0], dtype=torch.float64)
    normal = torch.nn.functional.normalize(radial, dim=1)
    layers = LayerOrder.build(pairs, normal, separation=torch.full((n,), 0.02, dtype=torch.float64))
    layered = replace(inp, cloth=replace(inp.cloth, layers=layers))
    model = PhysDrape(ModelConfig(variant="gnn")).double()
    inward = torch.zeros(2 * n, 6, dtype=torch.float64)
    inward[n:, :3] = -3.0 * normal  # 3 cm toward the axis: through the inner tube
    model.gnn.forward = lambda *args, **kwargs: inward
    crossed = model(inp).x_gnn
    assert float(layer_shortfall(crossed, layers).min()) > 0.01  # 1 cm through the inner tube
    assert float(layer_shortfall(layered.x_init, layers).max()) == 0.0
    kept = model(layered).x_gnn
    start = layer_shortfall(layered.x_init, layers)
    assert bool((layer_shortfall(kept, layers) <= start + 1e-9).all())
    torch.testing.assert_close(kept[:n], crossed[:n])  # the inner piece moves as the network moved it
