"""Strain limiting of X_init: stretched edges brought under the bound, the rest untouched."""

import pytest
import torch
from device_params import DEVICES
from torch import Tensor

from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.strain_limit import limit_edge_stretch, max_edge_stretch
from physdrape.geometry.topology import undirected_edges


@pytest.fixture
def sheet():
    v, f = grid_sheet(10, 10, width=0.2, height=0.2)
    v = torch.as_tensor(v, dtype=torch.float64)
    e = torch.from_numpy(undirected_edges(f))
    return v, e, (v[e[:, 1]] - v[e[:, 0]]).norm(dim=-1)


def test_a_pulled_vertex_is_brought_back_under_the_bound(sheet):
    v, e, rest = sheet
    x = v.clone()
    x[55, 1] += 0.08  # one vertex pulled 8 cm out of a 2 cm grid: ~4x stretch
    assert max_edge_stretch(x, e, rest) > 3.5
    y = limit_edge_stretch(x, e, rest, max_stretch=1.5)
    assert max_edge_stretch(y, e, rest) < 1.5 * 1.01
    far = (v - v[55]).norm(dim=-1) > 0.1
    assert torch.equal(y[far], x[far])  # untouched away from the stretched patch


def test_within_bound_is_the_identity_and_batches_match(sheet):
    v, e, rest = sheet
    x = v * 1.2  # uniform 1.2x stretch, inside the bound
    assert torch.equal(limit_edge_stretch(x, e, rest, max_stretch=1.5), x)
    pulled = v.clone()
    pulled[12, 1] += 0.06
    batch = torch.stack([x, pulled])
    out = limit_edge_stretch(batch, e, rest, max_stretch=1.5)
    assert torch.allclose(out[1], limit_edge_stretch(pulled, e, rest, max_stretch=1.5), atol=1e-12)


def test_min_stretch_pushes_a_compressed_patch_apart_and_leaves_the_rest(sheet):
    """min_stretch: edges shorter than min_stretch × rest are pushed apart toward it (within 1 %
    of it), edges between the bounds far from them keep their lengths; without it, compression
    is left as it is."""
    v, e, rest = sheet
    x = v.clone()
    near = (v - v[55]).norm(dim=-1) < 0.03
    x[near] = v[55] + 0.7 * (v[near] - v[55])  # a patch shrunk to 0.7 of its size
    length = (x[e[:, 1]] - x[e[:, 0]]).norm(dim=-1)
    assert (length / rest).min() < 0.75
    assert torch.equal(limit_edge_stretch(x, e, rest, max_stretch=1.5), x)
    y = limit_edge_stretch(x, e, rest, max_stretch=1.5, min_stretch=0.9)
    ratio = (y[e[:, 1]] - y[e[:, 0]]).norm(dim=-1) / rest
    assert ratio.min() > 0.9 * 0.99 and ratio.max() < 1.5
    far = (v - v[55]).norm(dim=-1) > 0.12
    assert torch.equal(y[far], x[far])
    with pytest.raises(ValueError, match="min_stretch"):
        limit_edge_stretch(x, e, rest, max_stretch=1.5, min_stretch=1.1)


def test_rejects_bad_arguments(sheet):
    v, e, rest = sheet
    with pytest.raises(ValueError, match="max_stretch"):
        limit_edge_stretch(v, e, rest, max_stretch=0.9)
    with pytest.raises(ValueError, match="rest_lengths"):
        limit_edge_stretch(v, e, rest[:-1])


def _sphere(radius: float, subdivisions: int = 3):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return torch.as_tensor(m.vertices, dtype=torch.float64), torch.as_tensor(m.faces, dtype=torch.int64)


def test_momentum_pulls_a_uniform_stretch_back_faster(sheet):
    v, e, rest = sheet
    x = v * 1.3
    plain = limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=40)
    heavy = limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=40, momentum=0.9)
    assert max_edge_stretch(heavy, e, rest) < max_edge_stretch(plain, e, rest) - 0.02
    converged = limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=400, momentum=0.9)
    assert max_edge_stretch(converged, e, rest) < 1.02 * 1.01


@pytest.fixture
def contracting_garment():
    """A sphere body (r = 10 cm) and a closed garment with rest radius 9.5 cm skinned at 13 cm:
    (body surface, positions, edges, rest lengths)."""
    from physdrape.geometry.proximity import BodySurface

    body_v, body_f = _sphere(0.1)
    rest_v, faces = _sphere(0.095)
    e = torch.from_numpy(undirected_edges(faces.numpy()))
    rest = (rest_v[e[:, 1]] - rest_v[e[:, 0]]).norm(dim=-1)
    return BodySurface(body_v[None], body_f), rest_v * (0.13 / 0.095), e, rest


def test_the_body_holds_a_contracting_garment_out(contracting_garment):
    """A closed garment whose rest state (r = 9.5 cm) is smaller than the body (10 cm), skinned at
    13 cm: unconstrained, limiting to 1.02 x rest pulls it inside (< 9.9 cm); with the body
    every vertex stops at the margin."""
    body, x, e, rest = contracting_garment
    free = limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=400, momentum=0.9)
    assert free.norm(dim=-1).max() < 0.099  # inside the 10 cm body
    held = limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=400, momentum=0.9, body=body, margin=2e-3)
    d = body.query(held).signed_distance
    assert d.min() > 0.9 * 2e-3 and d.max() < 4e-3


def test_contact_never_moves_what_needs_no_limiting():
    """A garment already inside the margin (1 mm off the body) and unstretched is returned as is:
    the limiter only stops its own moves from entering the margin, it does not resolve contact."""
    from physdrape.geometry.proximity import BodySurface

    body_v, body_f = _sphere(0.1)
    x, faces = _sphere(0.101)
    e = torch.from_numpy(undirected_edges(faces.numpy()))
    rest = (x[e[:, 1]] - x[e[:, 0]]).norm(dim=-1)
    out = limit_edge_stretch(x, e, rest, max_stretch=1.02, momentum=0.9,
                             body=BodySurface(body_v[None], body_f), margin=2e-3)
    assert torch.equal(out, x)


def reference_limit_edge_stretch(x, edges, rest_lengths, *, body=None, **kwargs):
    """The sweeps of `limit_edge_stretch` in plain torch ops (its slow reference twin), each mesh
    of a batch on its own (body: one per mesh)."""
    if x.ndim == 2:
        return _reference_one(x, edges, rest_lengths, body=body, **kwargs)
    meshes = x.reshape(-1, *x.shape[-2:])
    rest = rest_lengths.expand(*x.shape[:-2], edges.shape[0]).reshape(-1, edges.shape[0])
    return torch.stack([_reference_one(mesh, edges, rest[c], body=None if body is None else body.select(c), **kwargs)
                        for c, mesh in enumerate(meshes)]).reshape(x.shape)


def _reference_one(x, edges, rest_lengths, *, max_stretch=1.5, iterations=100, relaxation=1.5,
                   body=None, margin=2e-3, requery_every=10, reach=1e-2, momentum=0.0):
    """`reference_limit_edge_stretch` of one mesh."""
    # Work on the leading dimensions flattened into one (B·V, 3) mesh of B disjoint copies: a
    # 2-D index_add is much faster on CPU than one along dim -2 of a 3-D tensor.
    shape, num_verts = x.shape, x.shape[-2]
    flat = x.reshape(-1, 3)
    copies = flat.shape[0] // num_verts
    offsets = (torch.arange(copies, device=x.device) * num_verts)[:, None]
    i = (edges[:, 0][None] + offsets).reshape(-1)
    j = (edges[:, 1][None] + offsets).reshape(-1)
    ends = torch.cat([i, j])
    bound = (max_stretch * rest_lengths.to(x.dtype)).expand(*shape[:-2], edges.shape[0]).reshape(-1)
    planes, floor, found = None, None, None
    velocity = torch.zeros_like(flat)
    previous = None
    x = flat
    for sweep in range(iterations):
        if body is not None and sweep % requery_every == 0:
            # the vertices that may have come within reach of the body since their planes were found
            rows = (torch.arange(x.shape[0]) if found is None
                    else torch.nonzero(found[1] - (x - found[0]).norm(dim=-1) < reach)[:, 0])
            with torch.no_grad():  # in the body's dtype (the planes hold to its precision)
                query = body.query(x.detach()[rows].to(body.verts.dtype))
            closest, normal, distance = (t.to(x.dtype) for t in (query.closest, query.normal, query.signed_distance))
            if planes is None:
                planes, found = (closest, normal), (x.clone(), distance)
                floor = distance.clamp_max(margin)  # never deeper than at the start, never into the margin
            else:
                planes[0][rows], planes[1][rows], found[0][rows], found[1][rows] = closest, normal, x[rows], distance
        d = x[j] - x[i]
        length = d.norm(dim=-1)
        excess = (length - bound).clamp_min(0.0)
        inside = planes is not None and bool((_depth(x, planes, floor) > 1e-2 * margin).any())
        if not inside and not bool((excess > 1e-2 * bound).any()):
            break
        total = excess.sum()
        if previous is not None and bool(total > previous):
            velocity = torch.zeros_like(x)  # adaptive restart: the momentum overshot
        previous = total
        active = (excess > 0).to(x.dtype)
        # Each end moves half the excess along the edge; corrections are averaged per vertex.
        half = (0.5 * excess / length.clamp_min(1e-12)).unsqueeze(-1) * d
        shift = torch.zeros_like(x).index_add_(0, ends, torch.cat([half, -half]))
        count = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device).index_add_(0, ends, torch.cat([active, active]))
        x_new = x + relaxation * shift / count.clamp_min(1.0).unsqueeze(-1) + momentum * velocity
        if planes is not None:
            x_new = x_new + _depth(x_new, planes, floor).unsqueeze(-1) * planes[1]
        velocity = x_new - x
        x = x_new
    return x.reshape(shape)


def _depth(x: Tensor, planes: tuple[Tensor, Tensor], floor: Tensor) -> Tensor:
    """How far each vertex is below its floor (signed distance along its held closest-point
    plane) [m], >= 0."""
    closest, normal = planes
    return (floor - ((x - closest) * normal).sum(-1)).clamp_min(0.0)


@pytest.mark.parametrize("case", ["pulled", "uniform", "batch"])
@pytest.mark.parametrize("momentum", [0.0, 0.9])
def test_kernels_match_the_torch_reference(sheet, case, momentum):
    v, e, rest = sheet
    x = v.clone()
    if case == "pulled":
        x[55, 1] += 0.08
    elif case == "uniform":
        x = v * 1.3
    else:
        pulled = v.clone()
        pulled[12, 1] += 0.06
        x = torch.stack([v * 1.3, pulled])
    before = x.clone()
    for iterations in (3, 40):
        fast = limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=iterations, momentum=momentum)
        slow = reference_limit_edge_stretch(x, e, rest, max_stretch=1.02, iterations=iterations, momentum=momentum)
        torch.testing.assert_close(fast, slow, rtol=0.0, atol=1e-12)
    assert torch.equal(x, before)  # the input is not touched


def test_kernels_match_the_torch_reference_with_a_body(contracting_garment):
    body, x, e, rest = contracting_garment
    kwargs = {"max_stretch": 1.02, "iterations": 60, "momentum": 0.9, "body": body, "margin": 2e-3}
    torch.testing.assert_close(limit_edge_stretch(x, e, rest, **kwargs),
                               reference_limit_edge_stretch(x, e, rest, **kwargs), rtol=0.0, atol=1e-12)
    single = limit_edge_stretch(x.to(torch.float32), e, rest, **kwargs)
    assert single.dtype == torch.float32


def test_only_vertices_within_reach_are_queried_again(contracting_garment):
    """After the first query, a vertex is queried again only once it may have come within `reach`
    of the body (its distance then less its move since): the garment skinned 3 cm out is not
    searched again while it contracts from afar, and ends where querying every vertex at every
    requery leaves it (a plane held far from the body pushes nothing)."""
    body, x, e, rest = contracting_garment
    asked = []
    query = body.query

    def counting(points, **kwargs):
        asked.append(points.reshape(-1, 3).shape[0])
        return query(points, **kwargs)

    body.query = counting
    kwargs = {"max_stretch": 1.02, "iterations": 400, "momentum": 0.9, "body": body, "margin": 2e-3}
    out = limit_edge_stretch(x, e, rest, **kwargs)
    assert asked[0] == x.shape[0] and min(asked[1:]) == 0 and max(asked[1:]) == x.shape[0]
    calls = len(asked)
    every = limit_edge_stretch(x, e, rest, reach=float("inf"), **kwargs)
    assert set(asked[calls:]) == {x.shape[0]}
    torch.testing.assert_close(out, every, rtol=0.0, atol=1e-12)
    with pytest.raises(ValueError, match="reach"):
        limit_edge_stretch(x, e, rest, reach=-1.0, **kwargs)


def test_a_batch_ends_each_mesh_where_it_ends_alone(contracting_garment):
    """The meshes of a batch need different numbers of sweeps (one stretched more, one by a pulled
    vertex, on two bodies): each ends bit for bit where it ends draped alone, with its own
    restarts and its own stop."""
    from physdrape.geometry.proximity import BodySurface

    body, x, e, rest = contracting_garment
    pulled = x.clone()
    pulled[7] *= 1.3
    both = BodySurface(torch.stack([body.verts[0], 1.05 * body.verts[0]]), body.faces)
    kwargs = {"max_stretch": 1.02, "iterations": 60, "momentum": 0.9, "margin": 2e-3}
    batch = limit_edge_stretch(torch.stack([x, pulled]), e, rest, body=both, **kwargs)
    for c, alone in enumerate((x, pulled)):
        assert torch.equal(batch[c], limit_edge_stretch(alone, e, rest, body=both.select(c), **kwargs))
    torch.testing.assert_close(batch, reference_limit_edge_stretch(torch.stack([x, pulled]), e, rest, body=both,
                                                                   **kwargs), rtol=0.0, atol=1e-12)


def test_gradients_pass_straight_through(sheet):
    """The corrections are a fixed displacement for autograd: d(out)/d(x) is the identity."""
    v, e, rest = sheet
    x = v.clone()
    x[55, 1] += 0.08
    x.requires_grad_(True)
    out = limit_edge_stretch(x, e, rest, max_stretch=1.5)
    torch.testing.assert_close(out.detach(), limit_edge_stretch(x.detach(), e, rest, max_stretch=1.5))
    (out * torch.arange(out.numel(), dtype=out.dtype).reshape(out.shape)).sum().backward()
    torch.testing.assert_close(x.grad, torch.arange(x.numel(), dtype=x.dtype).reshape(x.shape))


@pytest.mark.parametrize("device", DEVICES)
def test_kernels_run_on_every_device(sheet, device):
    """The same sweeps on the CPU and on a GPU (the tensors' device), against the reference."""
    v, e, rest = sheet
    x = v.clone()
    x[55, 1] += 0.08
    out = limit_edge_stretch(x.to(device), e.to(device), rest.to(device), max_stretch=1.02, momentum=0.9)
    assert out.device.type == device
    torch.testing.assert_close(out.cpu(), reference_limit_edge_stretch(x, e, rest, max_stretch=1.02, momentum=0.9),
                               rtol=0.0, atol=1e-10)
