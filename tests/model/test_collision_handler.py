"""The collision handler's centroid pass (large faces whose interior dips into the body) and its
layer pass (an inner piece pushed out must not cross the piece over it)."""

import numpy as np
import pytest
import torch
import trimesh

from physdrape.geometry.proximity import BodySurface
from physdrape.model.collision_handler import EXIT_RADII, CollisionHandler, longest_per_row
from physdrape.physics.layers import LayerOrder, layer_energy

RADIUS = 0.1


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    return BodySurface(torch.tensor(np.asarray(mesh.vertices)), torch.tensor(np.asarray(mesh.faces)))


def chord_triangle(height: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A horizontal equilateral triangle centred over the sphere's pole at `height`, its
    vertices 5 cm from the axis: they are outside the sphere, its centroid is inside when
    height < RADIUS."""
    angles = torch.tensor([0.0, 2 * np.pi / 3, 4 * np.pi / 3], dtype=torch.float64)
    x = torch.stack([0.05 * torch.cos(angles), torch.full_like(angles, height), 0.05 * torch.sin(angles)], dim=1)
    return x, torch.tensor([[0, 1, 2]])


def test_the_centroid_pass_lifts_a_face_whose_interior_is_inside(sphere):
    x, faces = chord_triangle(0.097)
    body_index = torch.zeros(3, dtype=torch.int64)
    assert bool(sphere.query(x.mean(0, keepdim=True), body_index=body_index[:1]).inside.all())
    assert sphere.query(x, body_index=body_index).signed_distance.min() > 2e-3  # vertices clear of ε
    handler = CollisionHandler(margin=2e-3, centroid_margin=5e-4).double()
    with torch.no_grad():
        out = handler(x, sphere, body_index, faces=faces)
    centroid = sphere.query(out.mean(0, keepdim=True), body_index=body_index[:1])
    assert not bool(centroid.inside.any())
    assert float(centroid.signed_distance[0]) == pytest.approx(5e-4, abs=2e-5)  # pushed just to ε_c
    # one face: all three vertices take its push, along the body normal at the centroid (up, up
    # to the tilt of the icosphere's facet there)
    shift = out - x
    torch.testing.assert_close(shift, shift[:1].expand(3, 3), rtol=1e-9, atol=0)
    assert float(shift[0, 1]) > 2e-3 and float(shift[0, [0, 2]].norm()) < 0.1 * float(shift[0, 1])


def test_without_faces_or_with_a_zero_centroid_margin_it_is_the_vertex_handler(sphere):
    x, faces = chord_triangle(0.097)
    body_index = torch.zeros(3, dtype=torch.int64)
    plain = CollisionHandler(margin=2e-3, centroid_margin=0.0).double()
    with_pass = CollisionHandler(margin=2e-3, centroid_margin=5e-4).double()
    reference = plain(x, sphere, body_index)
    torch.testing.assert_close(plain(x, sphere, body_index, faces=faces), reference)
    torch.testing.assert_close(with_pass(x, sphere, body_index), reference)
    clear, _ = chord_triangle(0.12)  # nothing near the body: nothing moves
    torch.testing.assert_close(with_pass(clear, sphere, body_index, faces=faces), clear)


def test_the_centroid_pass_is_differentiable_and_only_pushes_outward(sphere):
    x, faces = chord_triangle(0.097)
    x = x.requires_grad_(True)
    body_index = torch.zeros(3, dtype=torch.int64)
    handler = CollisionHandler(margin=2e-3, centroid_margin=5e-4).double()
    out = handler(x, sphere, body_index, faces=faces)
    (grad,) = torch.autograd.grad(out[:, 1].sum(), x)
    assert torch.isfinite(grad).all() and grad.abs().sum() > 0
    before = sphere.query(x.detach(), body_index=body_index).signed_distance
    after = sphere.query(out.detach(), body_index=body_index).signed_distance
    assert bool((after >= before - 1e-12).all())


def test_bad_centroid_margin_is_refused():
    with pytest.raises(ValueError, match="centroid_margin"):
        CollisionHandler(centroid_margin=-1e-3)


def _stack(depths: list[float]) -> tuple[torch.Tensor, LayerOrder]:
    """One vertex per layer over the sphere's pole at RADIUS + depth (innermost first), each
    pair (outer, the one under it) kept 4 mm apart along the pole's normal."""
    x = torch.tensor([[0.0, RADIUS + d, 0.0] for d in depths], dtype=torch.float64)
    pairs = torch.tensor([[k + 1, k] for k in range(len(depths) - 1)])
    normal = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand(len(pairs), 3)
    return x, LayerOrder.build(pairs, normal)


def test_the_layer_pass_keeps_a_pushed_inner_piece_under_the_piece_over_it(sphere):
    """The inner layer dips 3 mm into the body and the middle one lies 4 mm over it: the body
    push drives the inner one 2 mm past the middle one, which the layer pass pushes out to 4 mm
    over it again; that reaches the outer one (6 mm over the middle one), pushed in the second
    pass. Each pair ends at its 4 mm gap, so the layer energy is what it was (zero)."""
    x, layers = _stack([-3e-3, 1e-3, 7e-3])
    body_index = torch.zeros(len(x), dtype=torch.int64)
    handler = CollisionHandler(margin=2e-3).double()
    with torch.no_grad():
        plain = handler(x, sphere, body_index)
        kept = handler(x, sphere, body_index, layers=layers)
    assert float(layer_energy(plain, layers).sum()) > 1e-3  # not vacuous: the plain handler crosses them
    torch.testing.assert_close(kept[0], plain[0])  # the body push itself is unchanged
    torch.testing.assert_close(kept[1:, 1] - kept[:-1, 1], torch.full((2,), 4e-3, dtype=torch.float64), rtol=0,
                               atol=1e-12)
    assert float(layer_energy(kept, layers).sum()) < 1e-18
    assert bool((kept[:, 1] >= plain[:, 1]).all())  # outward only


def test_the_layer_pass_leaves_separated_layers_and_existing_crossings_alone(sphere):
    body_index = torch.zeros(2, dtype=torch.int64)
    handler = CollisionHandler(margin=2e-3).double()
    with torch.no_grad():
        apart, layers = _stack([-3e-3, 2e-2])  # far apart: the inner push does not reach the outer piece
        torch.testing.assert_close(handler(apart, sphere, body_index, layers=layers),
                                   handler(apart, sphere, body_index))
        crossed, layers = _stack([5e-3, 4e-3])  # already crossed, nothing pushed: not the handler's business
        torch.testing.assert_close(handler(crossed, sphere, body_index, layers=layers), crossed)


def test_a_distance_bound_leaves_out_only_what_is_pushed_by_nothing(sphere):
    """A sheet over the sphere's pole (its middle inside, its rim centimetres off) and a bound
    from a query of it a few millimetres away: the handler with the bound queries fewer vertices
    and centroids and gives the same drape and gradients as without."""
    from physdrape.geometry.distance_bound import DistanceBound
    from physdrape.geometry.primitives import grid_sheet
    from physdrape.physics.contact import contact_samples

    verts, faces = grid_sheet(13, 13, width=0.24, height=0.24)
    x = torch.tensor(verts - verts.mean(0) + [0.0, 0.0985, 0.0], dtype=torch.float64)
    faces = torch.tensor(faces)
    body_index = torch.zeros(x.shape[0], dtype=torch.int64)
    gen = torch.Generator().manual_seed(2)
    earlier = x + 3e-3 * torch.rand(x.shape, generator=gen, dtype=torch.float64)
    samples = contact_samples(earlier, faces)
    bound = DistanceBound.of(samples, sphere.query(samples).signed_distance)
    handler = CollisionHandler(margin=2e-3, centroid_margin=5e-4).double()
    asked = []
    query = sphere.query

    def counting(points, **kwargs):
        asked.append(points.shape[0])
        return query(points, **kwargs)

    sphere.query = counting
    try:
        outs = []
        for b in (None, bound):
            xx = x.clone().requires_grad_(True)
            out = handler(xx, sphere, body_index, faces=faces, bound=b)
            grads = torch.autograd.grad((out * torch.arange(out.numel()).reshape(out.shape)).sum(),
                                        [xx, handler.delta_raw])
            outs.append((out.detach(), grads))
    finally:
        sphere.query = query
    assert asked[:2] == [x.shape[0], faces.shape[0]] and asked[2] < x.shape[0] / 2 and asked[3] < faces.shape[0] / 2
    assert float((outs[0][0] - x).norm(dim=-1).max()) > 1e-3  # the handler pushed something
    torch.testing.assert_close(outs[1][0], outs[0][0], rtol=0, atol=1e-15)
    for got, want in zip(outs[1][1], outs[0][1]):
        torch.testing.assert_close(got, want, rtol=0, atol=1e-12)


@pytest.fixture(scope="module")
def overlapping_spheres():
    """Two spheres of radius RADIUS whose centres are 1.5 RADIUS apart, as one triangle soup:
    a body with two parts sunk into each other (the surface of each inside the other stays)."""
    a = trimesh.creation.icosphere(subdivisions=4, radius=RADIUS)
    b = a.copy()
    b.apply_translation([1.5 * RADIUS, 0.0, 0.0])
    verts = np.concatenate([a.vertices, b.vertices])
    faces = np.concatenate([a.faces, b.faces + len(a.vertices)])
    return BodySurface(torch.tensor(verts), torch.tensor(faces))


def test_a_vertex_in_the_overlap_of_two_body_parts_ends_outside_both(overlapping_spheres):
    body = overlapping_spheres
    # 1.3 mm inside each sphere, near the rim of their overlap (as the vertices of a sleeve caught
    # at a bent elbow): the closest triangle is one of the first sphere's, buried in the second,
    # and a push along its normal lands inside the second
    x = torch.tensor([[0.75 * RADIUS, 0.64 * RADIUS, 0.0]], dtype=torch.float64)
    body_index = torch.zeros(1, dtype=torch.int64)
    query = body.query(x, body_index=body_index)
    assert bool(query.inside[0])
    normal_push = x + (2e-3 - query.signed_distance)[:, None] * query.normal
    assert bool(body.query(normal_push, body_index=body_index).inside[0])
    handler = CollisionHandler(margin=2e-3).double()
    x = x.requires_grad_(True)
    out = handler(x, body, body_index)
    after = body.query(out.detach(), body_index=body_index)
    assert not bool(after.inside[0]) and float(after.signed_distance[0]) >= 2e-3
    assert float((out - x).detach().norm()) < 0.02  # the shortest way out, not across the body
    (grad,) = torch.autograd.grad(out.sum(), x)
    assert torch.isfinite(grad).all()


def test_a_face_in_the_overlap_of_two_body_parts_ends_with_its_centroid_outside(overlapping_spheres):
    body = overlapping_spheres
    centre = torch.tensor([0.75 * RADIUS, 0.64 * RADIUS, 0.0], dtype=torch.float64)
    angles = torch.tensor([0.0, 2 * np.pi / 3, 4 * np.pi / 3], dtype=torch.float64)
    x = centre + 2e-3 * torch.stack([torch.zeros_like(angles), torch.cos(angles), torch.sin(angles)], dim=1)
    body_index = torch.zeros(3, dtype=torch.int64)
    faces = torch.tensor([[0, 1, 2]])
    assert bool(body.query(centre[None], body_index=body_index[:1]).inside[0])
    handler = CollisionHandler(margin=2e-3, centroid_margin=5e-4).double()
    with torch.no_grad():
        out = handler(x, body, body_index, faces=faces)
    assert not bool(body.query(out.mean(0, keepdim=True), body_index=body_index[:1]).inside[0])
    assert not bool(body.query(out, body_index=body_index).inside.any())


def test_a_vertex_of_several_stuck_faces_takes_the_longest_offset_not_their_sum():
    rows = torch.tensor([2, 0, 2, 2, 0])
    offsets = torch.tensor([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 3.0], [3.0, 0, 0], [0, -1.0, 0]], dtype=torch.float64)
    field = longest_per_row(rows, offsets, 4)
    torch.testing.assert_close(field, torch.tensor([[0, 2.0, 0], [0, 0, 0], [0, 0, 3.0], [0, 0, 0]],
                                                   dtype=torch.float64))  # a tie: the first given


def _fan(centre: torch.Tensor, radius: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A hexagonal fan of six faces around a centre vertex (0) in the plane z = centre's."""
    angles = torch.arange(6, dtype=torch.float64) * (np.pi / 3)
    rim = centre + radius * torch.stack([torch.cos(angles), torch.sin(angles), torch.zeros_like(angles)], dim=1)
    faces = torch.tensor([[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)])
    return torch.cat([centre[None], rim]), faces


def test_what_is_freed_from_an_overlap_moves_at_most_the_longest_exit_radius(overlapping_spheres):
    body = overlapping_spheres
    # a fan near the rim of the two spheres' overlap, every vertex and centroid inside: each face
    # asks its corners out, and the centre vertex is a corner of all six
    x, faces = _fan(torch.tensor([0.75 * RADIUS, 0.64 * RADIUS, 0.0], dtype=torch.float64), 1e-3)
    body_index = torch.zeros(len(x), dtype=torch.int64)
    assert bool(body.query(x, body_index=body_index).inside.all())
    handler = CollisionHandler(margin=2e-3, centroid_margin=5e-4).double()
    with torch.no_grad():
        out = handler._free_stuck(x, faces, body, body_index, torch.arange(len(x)))
    moved = (out - x).norm(dim=1)
    assert float(moved.max()) <= EXIT_RADII[-1] * (1 + 1e-9)
    assert float(moved.min()) > 0  # and they did move out


def test_a_vertex_with_no_way_out_within_the_exit_radii_stays_where_it_is(overlapping_spheres):
    body = overlapping_spheres
    # the middle of the two spheres' overlap: 6.6 cm from outside in any direction (cloth caught
    # where an arm is pressed into the torso): no offset frees it, and none throws it deeper
    x = torch.tensor([[0.75 * RADIUS, 0.0, 0.0]], dtype=torch.float64)
    body_index = torch.zeros(1, dtype=torch.int64)
    assert bool(body.query(x, body_index=body_index).inside[0])
    handler = CollisionHandler(margin=2e-3).double()
    with torch.no_grad():
        out = handler._free_stuck(x, None, body, body_index, torch.tensor([0]))
    torch.testing.assert_close(out, x, rtol=0, atol=0)


def test_what_stays_inside_an_overlap_is_left_where_it_was(overlapping_spheres):
    """Deep in the two spheres' overlap (cloth caught between thighs pressed together) the push
    along the normal only carries a vertex from one sphere into the other: the handler leaves it
    where it was, values and gradient, rather than tear it from its neighbours."""
    body = overlapping_spheres
    x = torch.tensor([[0.75 * RADIUS, 0.0, 0.0], [0.75 * RADIUS, 0.02, 0.01]], dtype=torch.float64,
                     requires_grad=True)
    body_index = torch.zeros(2, dtype=torch.int64)
    handler = CollisionHandler(margin=2e-3).double()
    out = handler(x, body, body_index)
    torch.testing.assert_close(out, x, rtol=0, atol=0)
    (grad,) = torch.autograd.grad(out.sum(), x)
    torch.testing.assert_close(grad, torch.ones_like(x))

