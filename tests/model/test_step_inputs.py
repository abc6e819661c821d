"""The solver's first step as network input (`ModelConfig.step_inputs`)."""

import pytest
import torch
from drape_cases import layered_tubes, make_input, tube

from physdrape.model import ModelConfig, PhysDrape, Variant
from physdrape.model.features import NEWTON_FEATURES, NODE_FEATURES, STEP_FEATURES
from physdrape.model.stretching_solver import StretchingSolver
from physdrape.physics.contact import plane_contact_forces, query_samples
from physdrape.physics.forces import internal_forces
from physdrape.train.loss import LossConfig, drape_loss

MODEL = ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY, step_inputs=True)


def _stretched():
    """Two tubes on their spheres, stretched 3 % along the axis and sheared: F ≠ 0, contact active."""
    tubes = [tube(6, 16, 0.14, dtype=torch.float64, name="a"), tube(5, 13, 0.17, dtype=torch.float64, name="b")]
    batch = make_input(tubes, [0.15, 0.13], dtype=torch.float64)
    x = batch.x_init * torch.tensor([1.0, 1.03, 1.0], dtype=torch.float64)
    x = x + 0.01 * torch.sin(7.0 * x[:, 1:2]) * torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    return batch, x


def test_step_parts_add_up_to_the_preconditioned_force():
    """Unclipped, the block-Jacobi and coarse parts sum to C F, F the internal and contact forces
    on planes queried at x: the first step's direction of a solve from x."""
    batch, x = _stretched()
    solver = StretchingSolver(kind="two_level", eta=1.0, margin=MODEL.margin, contact_stiffness=MODEL.contact_stiffness,
                              max_step=0.0)
    local, coarse = solver.step_parts(x, batch.cloth, bodies=batch.bodies, body_index=batch.body_index)
    q = query_samples(x, batch.cloth.faces, batch.bodies, batch.body_index)
    force = internal_forces(x, batch.cloth) + plane_contact_forces(
        x, batch.cloth.faces, q.closest.to(x.dtype), q.normal.to(x.dtype), stiffness=MODEL.contact_stiffness,
        margin=MODEL.margin)
    precondition = solver.preconditioner(x, batch.cloth, bodies=batch.bodies, body_index=batch.body_index)
    torch.testing.assert_close(local + coarse, precondition(force), rtol=1e-8, atol=1e-12)
    assert float(coarse.norm()) > 0.1 * float(local.norm())  # the coarse part is not negligible here
    short = StretchingSolver(kind="two_level", eta=1.0, margin=MODEL.margin, contact_stiffness=MODEL.contact_stiffness,
                             max_step=1e-4)
    clipped = short.step_parts(x, batch.cloth, bodies=batch.bodies, body_index=batch.body_index)
    for part in clipped:
        assert float(part.norm(dim=-1).max()) <= 1e-4 * (1 + 1e-9)


def test_the_network_reads_the_step_parts_and_trains():
    torch.manual_seed(0)
    batch, _ = _stretched()
    model = PhysDrape(MODEL).double()
    nodes, _, _ = model.graph_inputs(batch)
    assert nodes.shape[1] == NODE_FEATURES + STEP_FEATURES
    local, coarse = model.solver.step_parts(batch.x_init, batch.cloth, bodies=batch.bodies, body_index=batch.body_index)
    torch.testing.assert_close(nodes[:, NODE_FEATURES:], torch.cat([local, coarse], dim=-1))
    # the one query of the vertices and centroids gives the vertices' distance column as a query of the vertices
    distance = batch.bodies.query(batch.x_init, body_index=batch.body_index).signed_distance
    torch.testing.assert_close(nodes[:, 3], distance)
    out = model(batch)
    loss, _ = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, LossConfig(),
                         contact_stiffness=MODEL.contact_stiffness, margin=MODEL.margin)
    loss.backward()
    first = model.gnn.node_encoder[0].weight.grad
    assert first.shape[1] == NODE_FEATURES + STEP_FEATURES and float(first[:, NODE_FEATURES:].abs().sum()) > 0


def test_step_inputs_need_the_two_level_solver():
    with pytest.raises(ValueError, match="two_level"):
        ModelConfig(step_inputs=True, solver="explicit")


def test_the_step_parts_need_only_the_centroids_within_the_contact_reach():
    """With the face centroids beyond the contact's reach (by their corners' distances) left
    unqueried, the step parts are those of the full query, to rounding."""
    from physdrape.physics.contact import query_samples, query_samples_near

    batch, x = _stretched()
    x = x + torch.tensor([0.0, 0.08, 0.0], dtype=x.dtype)  # partly off the spheres: some centroids far
    solver = StretchingSolver(kind="two_level", eta=1.0, margin=MODEL.margin, contact_stiffness=MODEL.contact_stiffness)
    reach = max(solver.contact_band, solver.margin)
    faces = batch.cloth.faces
    full = query_samples(x, faces, batch.bodies, batch.body_index)
    near = query_samples_near(x, faces, batch.bodies, batch.body_index, reach=reach)
    num_verts = x.shape[0]
    stand_in = near.face[num_verts:] < 0
    assert 0 < int(stand_in.sum()) < len(stand_in)
    assert bool((full.signed_distance[num_verts:][stand_in] >= reach).all())
    bound, exact = near.signed_distance[num_verts:][stand_in], full.signed_distance[num_verts:][stand_in]
    assert bool((bound <= exact + 1e-12).all())  # the stand-in's distance is a lower bound
    for name in ("closest", "normal", "signed_distance", "face"):
        kept = torch.cat([torch.ones(num_verts, dtype=torch.bool), ~stand_in])
        torch.testing.assert_close(getattr(near, name)[kept], getattr(full, name)[kept])
    args = {"bodies": batch.bodies, "body_index": batch.body_index}
    for got, want in zip(solver.step_parts(x, batch.cloth, query=near, **args),
                         solver.step_parts(x, batch.cloth, query=full, **args), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-10, atol=1e-14)


def test_the_newton_part_is_the_preconditioned_step_refined_by_conjugate_gradients():
    """One iteration: each garment's C F scaled to the quadratic model's minimum along it
    (parallel to the two parts' sum; the iterations themselves are `_truncated_newton`'s, tested
    with the solver); more iterations turn it; clipped to the step clip like the parts."""
    batch, x = _stretched()
    solver = StretchingSolver(kind="two_level", eta=1.0, margin=MODEL.margin, contact_stiffness=MODEL.contact_stiffness,
                              max_step=0.0)
    args = {"bodies": batch.bodies, "body_index": batch.body_index}
    local, coarse, one = solver.step_parts(x, batch.cloth, newton_iterations=1, **args)
    plain = local + coarse
    for garment in range(2):  # each garment's own scale
        rows = batch.cloth.vert_garment == garment
        scale = float((one[rows] * plain[rows]).sum() / (plain[rows] * plain[rows]).sum())
        assert scale > 0
        torch.testing.assert_close(one[rows], scale * plain[rows], rtol=1e-8, atol=1e-12)
    three = solver.step_parts(x, batch.cloth, newton_iterations=3, **args)[2]
    first = batch.cloth.vert_garment == 0  # the other tube slides freely: its unclipped moves are huge
    assert float(torch.nn.functional.cosine_similarity(three[first].flatten(), one[first].flatten(), dim=0)) < 0.99
    assert len(solver.step_parts(x, batch.cloth, **args)) == 2  # no Newton part unless asked
    clipping = StretchingSolver(kind="two_level", eta=1.0, margin=MODEL.margin,
                                contact_stiffness=MODEL.contact_stiffness, max_step=1e-3)
    clipped = clipping.step_parts(x, batch.cloth, newton_iterations=3, **args)[2]
    assert float(clipped.norm(dim=-1).max()) <= 1e-3 * (1 + 1e-9)


def test_the_network_reads_the_newton_part():
    torch.manual_seed(0)
    batch, _ = _stretched()
    model = PhysDrape(ModelConfig(latent=16, blocks=2, levels=1, variant=Variant.GNN_ONLY, step_inputs=True,
                                  step_newton_iterations=2)).double()
    nodes, _, _ = model.graph_inputs(batch)
    assert nodes.shape[1] == NODE_FEATURES + STEP_FEATURES + NEWTON_FEATURES
    parts = model.solver.step_parts(batch.x_init, batch.cloth, bodies=batch.bodies, body_index=batch.body_index,
                                    newton_iterations=2)
    torch.testing.assert_close(nodes[:, NODE_FEATURES:], torch.cat(parts, dim=-1))


@pytest.mark.parametrize("settings, message", [
    ({"step_newton_iterations": 2}, "step_inputs: true"),
    ({"step_inputs": True, "step_newton_iterations": -1}, "≥ 0"),
    ({"step_inputs": True, "step_newton_iterations": 2, "look_back_blocks": 3}, "look_back_blocks"),
])
def test_the_newton_part_is_checked(settings, message):
    with pytest.raises(ValueError, match=message):
        ModelConfig(**settings)


def test_the_step_inputs_read_the_layer_pairs_along_their_normals_only():
    """A multi-piece garment's step inputs come from a preconditioner whose layer pairs act along
    their normals only (`INPUT_LAYER_SLIDE`, 0), not with the solver's tangential share, which
    holds the outer piece to the inner one's sliding."""
    from physdrape.model.physdrape import INPUT_LAYER_SLIDE

    batch = layered_tubes(0.15, separation=0.02)
    n = batch.garments.num_verts // 2
    model = PhysDrape(MODEL).double()
    nodes, _, _ = model.graph_inputs(batch)
    step = model.solver.step_parts(batch.x_init, batch.cloth, bodies=batch.bodies, body_index=batch.body_index,
                                   layer_slide=INPUT_LAYER_SLIDE)
    torch.testing.assert_close(nodes[:, NODE_FEATURES:], torch.cat(step, dim=-1))
    assert INPUT_LAYER_SLIDE == 0.0
    held = model.solver.step_parts(batch.x_init, batch.cloth, bodies=batch.bodies, body_index=batch.body_index)
    # the solver's own share holds the pieces' relative sliding: the outer tube's coarse move differs
    assert float((held[1][n:] - step[1][n:]).norm()) > 0.1 * float(step[1][n:].norm())
