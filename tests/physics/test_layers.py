"""The layer order (physics.layers): forces = −∇E (autograd and central differences, float64),
exact PSD pair Hessian, one-sidedness, its place in the shared energy, and the oracle keeping an
outer sheet outside an inner one."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from physics_cases import (
    assembled_pair_hessian,
    assert_force_is_negative_gradient,
    deformed,
)

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.proximity import BodySurface
from physdrape.physics import (
    Cloth,
    energy_terms,
    internal_energy,
    internal_forces,
    relax,
)
from physdrape.physics.layers import (
    DEFAULT_LAYER_GAP,
    DEFAULT_LAYER_STIFFNESS,
    MIN_LAYER_GAP,
    LayerOrder,
    layer_energy,
    layer_forces,
    layer_pair_blocks,
    layer_shortfall,
    push_outer_out,
)


def make_layers(garment, x: torch.Tensor, seed: int = 0, count: int = 10, *, active: bool = True) -> LayerOrder:
    gen = torch.Generator().manual_seed(seed)
    pairs = torch.randperm(garment.num_verts, generator=gen)[:2 * count].reshape(count, 2)
    normal = torch.randn(count, 3, generator=gen, dtype=torch.float64)
    normal = normal / normal.norm(dim=-1, keepdim=True)
    sep = ((x[pairs[:, 0]] - x[pairs[:, 1]]) * normal).sum(-1)
    gap = sep + (0.01 if active else -0.01)
    return LayerOrder(pairs=pairs, normal=normal, gap=gap,
                      stiffness=100.0 + 100.0 * torch.rand(count, generator=gen, dtype=torch.float64))


@pytest.mark.parametrize("mesh", ["sheet", "tube"])
@pytest.mark.parametrize("seed", [0, 1])
def test_layer_force_equals_negative_gradient(mesh, seed, request):
    garment = request.getfixturevalue(mesh)
    x = deformed(garment, seed=seed)
    layers = make_layers(garment, x, seed)
    assert_force_is_negative_gradient(lambda y: layer_energy(y, layers), lambda y: layer_forces(y, layers), x,
                                      seed=seed + 11, min_gradient=1e-3)


def test_layer_hessian_is_exact_psd_and_one_sided(sheet):
    x = deformed(sheet, seed=4)
    layers = make_layers(sheet, x, 4, count=3)
    full = torch.autograd.functional.hessian(lambda y: layer_energy(y, layers).sum(), x)
    full = full.reshape(sheet.num_verts * 3, sheet.num_verts * 3)
    assembled = assembled_pair_hessian(layers.pairs, layer_pair_blocks(x, layers), sheet.num_verts)
    assert full.abs().max() > 10.0
    torch.testing.assert_close(assembled, full, rtol=1e-9, atol=1e-9)
    assert float(torch.linalg.eigvalsh(layer_pair_blocks(x, layers)).min()) >= -1e-12
    apart = make_layers(sheet, x, 4, count=3, active=False)  # already far enough apart: no term
    assert float(layer_energy(x, apart).abs().max()) == 0.0
    assert float(layer_forces(x, apart).abs().max()) == 0.0


def test_layers_are_part_of_the_shared_energy(tube):
    x = deformed(tube, seed=6)
    layers = make_layers(tube, x, 6)
    cloth = Cloth.build(tube)
    layered = replace(cloth, layers=layers)
    e = layer_energy(x, layers).sum()
    assert float(e) > 1e-6
    assert float(energy_terms(x, layered)["layer"]) == pytest.approx(float(e), rel=1e-12)
    assert float(internal_energy(x, layered) - internal_energy(x, cloth)) == pytest.approx(float(e), rel=1e-9)
    torch.testing.assert_close(internal_forces(x, layered) - internal_forces(x, cloth), layer_forces(x, layers))
    assert layered.to(torch.float32).layers.normal.dtype == torch.float32
    assert Cloth.build(tube).with_terms_of(layered).layers is not None


def _sheet(n: int, size: float, offset) -> tuple[torch.Tensor, torch.Tensor]:
    """An n × n grid sheet of side `size` [m] in the xz plane at `offset`, its faces facing up."""
    g = torch.linspace(0.0, size, n, dtype=torch.float64)
    xx, zz = torch.meshgrid(g, g, indexing="ij")
    grid = torch.stack([xx.reshape(-1), torch.zeros(n * n, dtype=torch.float64), zz.reshape(-1)], -1)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, i * n + j + 1, (i + 1) * n + j, (i + 1) * n + j + 1
            faces += [(a, b, d), (a, d, c)]
    return grid + torch.tensor(offset, dtype=torch.float64), torch.tensor(faces)


def test_oracle_keeps_the_outer_sheet_outside():
    """Two flat sheets, the outer authored 1 mm above the inner, started 3 mm below it (through it):
    with the layer order the oracle puts the outer back outside; without it, it stays through."""
    n = 6
    grid, faces = _sheet(n, 0.05, [0.0, 0.0, 0.0])
    inner = Garment.from_mesh(grid, faces, dtype=torch.float64)
    outer = Garment.from_mesh(grid + torch.tensor([0.0, 1e-3, 0.0], dtype=torch.float64), faces, dtype=torch.float64)
    batch = GarmentBatch.pack([inner, outer])
    cloth = replace(Cloth.build(batch), gravity=torch.zeros(2, 3, dtype=torch.float64))
    pairs = torch.stack([torch.arange(n * n) + n * n, torch.arange(n * n)], 1)
    up = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand(n * n, 3)
    layers = LayerOrder(pairs=pairs, normal=up, gap=torch.full((n * n,), 1e-3, dtype=torch.float64),
                        stiffness=torch.full((n * n,), 1000.0, dtype=torch.float64))
    x = batch.rest.clone()
    x[n * n:, 1] -= 4e-3  # the whole outer sheet through the inner one
    verts = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64) * 0.01 + 5.0
    bodies = BodySurface(verts, torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))  # far: no contact
    body_index = torch.zeros(2, dtype=torch.int64)
    free = relax(x, cloth, bodies, body_index, max_iters=20)
    held = relax(x, replace(cloth, layers=layers), bodies, body_index, max_iters=20)
    assert "layer" in held.energy_terms
    def separation(r):
        return r.x[n * n:, 1] - r.x[:n * n, 1]

    assert float(separation(held).min()) > 0.9e-3
    assert float(separation(free).max()) < -2e-3


def test_layer_order_keeps_the_template_gap_within_bounds():
    pairs = torch.tensor([[0, 1], [2, 3], [4, 5]])
    normal = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand(3, 3)
    built = LayerOrder.build(pairs, normal, separation=torch.tensor([2e-4, 2e-3, 1e-2], dtype=torch.float64))
    torch.testing.assert_close(built.gap, torch.tensor([MIN_LAYER_GAP, 2e-3, DEFAULT_LAYER_GAP], dtype=torch.float64))
    assert built.stiffness.tolist() == [DEFAULT_LAYER_STIFFNESS] * 3
    assert LayerOrder.build(pairs, normal).gap.tolist() == [DEFAULT_LAYER_GAP] * 3


@pytest.mark.parametrize("active", [True, False])
def test_the_links_blocks_majorise_the_stitches_and_layer_pairs_exact_blocks(sheet, active):
    """The preconditioners' link blocks H (`physics.forces.links`) are ≥ each pair's exact 3×3
    block, so [[H, −H], [−H, H]] majorises the pair's Hessian; x-independent, the same whether
    the pairs are active or not."""
    from test_stitches import make_stitches

    from physdrape.physics.forces import links
    from physdrape.physics.stitches import stitch_pair_blocks

    x = deformed(sheet, seed=5)
    layers = make_layers(sheet, x, 5, count=6, active=active)
    stitches = make_stitches(sheet, x, 6, count=6, taut=active)
    cloth = replace(Cloth.build(sheet), stitches=stitches, layers=layers)
    tied = links(cloth)
    assert torch.equal(tied.pairs, torch.cat([stitches.pairs, layers.pairs]))
    exact = torch.cat([stitch_pair_blocks(x, stitches), layer_pair_blocks(x, layers)])
    assert bool((exact.abs().amax(dim=(1, 2)) > 0).all()) == active  # not vacuous where active
    assert torch.linalg.eigvalsh(tied.blocks - exact).min() > -1e-9 * tied.blocks.abs().max()
    # a layer pair's block is stiffest along its normal
    n = layers.normal
    along = torch.einsum("pi,pij,pj->p", n, tied.blocks[len(stitches.pairs):], n)
    torch.testing.assert_close(along, layers.stiffness)


def test_pushing_the_outer_vertices_out_puts_the_layers_in_order_or_within_what_is_allowed(sheet):
    x = deformed(sheet, seed=7)
    layers = make_layers(sheet, x, 7, count=8)  # every pair short of its gap by 1 cm
    assert bool((layer_shortfall(x, layers) > 5e-3).all())
    pushed = push_outer_out(x, layers)
    torch.testing.assert_close(layer_shortfall(pushed, layers), torch.zeros(8, dtype=torch.float64), rtol=0,
                               atol=1e-12)
    moved = pushed - x
    outer = layers.pairs[:, 0]
    assert bool((moved.abs().sum(-1) > 0).sum() == 8) and bool((moved[outer].abs().sum(-1) > 0).all())
    torch.testing.assert_close(moved[outer], 1e-2 * layers.normal, rtol=0, atol=1e-12)  # along n, by the shortfall
    allowed = torch.full((8,), 4e-3, dtype=torch.float64)
    torch.testing.assert_close(layer_shortfall(push_outer_out(x, layers, allowed), layers), allowed, rtol=0, atol=1e-12)


def _sheets_order(verts: torch.Tensor, faces: torch.Tensor, n: int, pairs: torch.Tensor | None = None) -> LayerOrder:
    """The layer order of two n × n sheets (inner first) with the template's `pairs` (default none,
    their normals up) and what `follow_pairs` needs."""
    pairs = torch.zeros(0, 2, dtype=torch.int64) if pairs is None else pairs
    up = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand(len(pairs), 3)
    return LayerOrder(pairs, up, torch.full((len(pairs),), 1e-3, dtype=torch.float64),
                      torch.full((len(pairs),), 1000.0, dtype=torch.float64),
                      piece=torch.repeat_interleave(torch.arange(2), n * n),
                      together=torch.ones(2, 2, dtype=torch.bool),
                      depth=verts[:, 1].clone(), faces=faces)


def test_follow_pairs_hold_each_vertex_on_its_side_of_the_other_sheet():
    """An outer sheet 6 mm over an inner one and shifted by 2.5 cm (half its side): each outer
    vertex over the inner sheet is paired with a corner of the face under it, each inner vertex
    under the outer sheet with a corner of the face over it, in [outer, inner] order, the normal
    the faces' (up); the vertices beyond the other sheet's border are not paired; a pair's
    separation along its normal is the sheets' 6 mm. Turned upside down, the same pairs in the
    other order."""
    from physdrape.physics.layers import follow_pairs

    n = 11
    inner, faces = _sheet(n, 0.05, [0.0, 0.0, 0.0])
    outer, _ = _sheet(n, 0.05, [0.025, 0.006, 0.0])
    verts, faces = torch.cat([inner, outer]), torch.cat([faces, faces + n * n])
    layers = _sheets_order(verts, faces, n)
    pairs, normal = follow_pairs(verts, layers)
    assert bool((layers.piece[pairs[:, 0]] == 1).all()) and bool((layers.piece[pairs[:, 1]] == 0).all())
    torch.testing.assert_close(normal, torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64).expand_as(normal))
    separation = ((verts[pairs[:, 0]] - verts[pairs[:, 1]]) * normal).sum(-1)
    torch.testing.assert_close(separation, torch.full_like(separation, 0.006))
    held_outer, held_inner = set(pairs[:, 0].tolist()), set(pairs[:, 1].tolist())
    over_inner = [v for v in range(n * n, 2 * n * n) if verts[v, 0] <= 0.05 + 1e-9]
    under_outer = [v for v in range(n * n) if verts[v, 0] >= 0.025 - 1e-9]
    assert set(over_inner) <= held_outer and len(held_outer) == len(over_inner)
    assert set(under_outer) <= held_inner
    flipped = verts * torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)  # the outer sheet now under
    pairs_flipped, _ = follow_pairs(flipped, replace(layers, depth=flipped[:, 1].clone()))
    assert bool((layers.piece[pairs_flipped[:, 0]] == 0).all())
    assert set(map(tuple, pairs_flipped.flip(1).tolist())) == set(map(tuple, pairs.tolist()))


def test_follow_pairs_find_faces_again_after_the_faces_change_in_place():
    """The faces table `follow_pairs` keeps per faces tensor is made again when that tensor is
    changed in place (its faces reordered): the pairs are those of a fresh copy of the new faces."""
    from physdrape.physics.layers import follow_pairs

    n = 6
    inner, faces = _sheet(n, 0.05, [0.0, 0.0, 0.0])
    outer, _ = _sheet(n, 0.05, [0.01, 0.006, 0.0])
    verts, faces = torch.cat([inner, outer]), torch.cat([faces, faces + n * n])
    layers = _sheets_order(verts, faces, n)
    before = follow_pairs(verts, layers)
    layers.faces.copy_(layers.faces.flip(0))  # the same faces in the opposite order
    after = follow_pairs(verts, layers)
    fresh = follow_pairs(verts, replace(layers, faces=layers.faces.clone()))
    assert all(torch.equal(a, b) for a, b in zip(after, fresh))
    assert set(map(tuple, after[0].tolist())) == set(map(tuple, before[0].tolist()))


def test_follow_pairs_pair_the_pieces_of_one_garment_only():
    """Four sheets stacked 6 mm apart, the lower three the pieces of one garment, the top one a
    garment of its own: every vertex of each of the three is held against each of the other two
    (the upper piece outer), and the fourth sheet gets no pair, though it lies 6 mm over the third."""
    from physdrape.physics.layers import follow_pairs

    n = 6
    sheets = [_sheet(n, 0.05, [0.0, 0.006 * k, 0.0]) for k in range(4)]
    verts = torch.cat([v for v, _ in sheets])
    faces = torch.cat([f + k * n * n for k, (_, f) in enumerate(sheets)])
    together = torch.zeros(4, 4, dtype=torch.bool)
    together[:3, :3] = True
    together[3, 3] = True
    layers = replace(_sheets_order(verts, faces, n), piece=torch.repeat_interleave(torch.arange(4), n * n),
                     together=together)
    pairs, _ = follow_pairs(verts, layers)
    piece = layers.piece[pairs]
    assert not bool((piece == 3).any())
    assert set(map(tuple, piece.tolist())) == {(1, 0), (2, 0), (2, 1)}
    for upper, lower in ((1, 0), (2, 0), (2, 1)):
        between = pairs[(piece[:, 0] == upper) & (piece[:, 1] == lower)]
        assert set(between[:, 0].tolist()) == set(range(upper * n * n, (upper + 1) * n * n))  # each outer vertex
        assert set(between[:, 1].tolist()) == set(range(lower * n * n, (lower + 1) * n * n))  # each inner one


def _slid_sheets_over_a_slab(depth: float = 5e-3):
    """Two 6 × 6 sheets over a slab whose top lies `depth` [m] under the inner one, the outer sheet authored
    beside the inner one (only its nearest columns within the template pairs' reach) and slid over
    it, 3 mm above it: (x, cloth, the layer order that follows, the template's pairs alone,
    bodies, the outer sheet's separation from the inner one at x → (36,))."""
    n = 6
    inner, faces = _sheet(n, 0.05, [0.0, 0.0, 0.0])
    outer, _ = _sheet(n, 0.05, [0.08, 1e-3, 0.0])
    batch = GarmentBatch.pack([Garment.from_mesh(torch.cat([inner, outer]), torch.cat([faces, faces + n * n]),
                                                 dtype=torch.float64)])  # one garment of two pieces
    cloth = Cloth.build(batch)
    near = (batch.rest[n * n:, None] - batch.rest[None, :n * n]).norm(dim=-1).argmin(1)
    close = (batch.rest[n * n:] - batch.rest[near]).norm(dim=-1) <= 0.04
    pairs = torch.stack([torch.arange(n * n, 2 * n * n)[close], near[close]], 1)
    assert 0 < len(pairs) < n * n
    follows = _sheets_order(batch.rest, batch.faces, n, pairs)
    fixed = replace(follows, piece=None, together=None, depth=None, faces=None)
    x = batch.rest.clone()
    x[n * n:] += torch.tensor([-0.08, 2e-3, 0.0], dtype=torch.float64)  # over the inner sheet, 3 mm above it
    corners = torch.tensor([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)], dtype=torch.float64)
    verts = corners * torch.tensor([0.5, 0.1, 0.5], dtype=torch.float64) - torch.tensor([0.0, 0.1 + depth, 0.0],
                                                                                        dtype=torch.float64)
    box = torch.tensor([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    facing = torch.linalg.cross(verts[box[:, 1]] - verts[box[:, 0]], verts[box[:, 2]] - verts[box[:, 0]])
    flip = (facing * (verts[box].mean(1) - verts.mean(0))).sum(-1) < 0
    box[flip] = box[flip].flip(1)
    return x, cloth, follows, fixed, BodySurface(verts, box), lambda y: y[n * n:, 1] - y[:n * n, 1]


def test_oracle_keeps_a_slid_sheet_on_its_side_of_the_other():
    """Both sheets falling onto the slab: the oracle that completes the pairs where the sheets are
    (`physics.layers.follow_pairs`) rests the whole outer sheet on the inner one; with the
    template's pairs alone, the columns that had none fall through it to the slab."""
    x, cloth, follows, fixed, bodies, separation = _slid_sheets_over_a_slab()
    body_index = torch.zeros(1, dtype=torch.int64)
    held = relax(x, replace(cloth, layers=follows), bodies, body_index, max_iters=60)
    left = relax(x, replace(cloth, layers=fixed), bodies, body_index, max_iters=60)
    assert float(separation(held.x).min()) > 0.9e-3
    assert float(separation(left.x).min()) < 0.5e-3


def test_the_solver_keeps_a_slid_sheet_on_its_side_of_the_other():
    """The outer sheet pressed onto the inner one (a force f̂ of 0.01 N down on each of its
    vertices) through the two-level solver's steps: at its full body queries the solver completes
    the pairs where the sheets are, as the oracle does, and the outer sheet stays on the inner
    one, at its 1 mm gap; with the template's pairs alone, the columns that had none go through."""
    from physdrape.model.stretching_solver import StretchingSolver

    x, cloth, follows, fixed, bodies, separation = _slid_sheets_over_a_slab()
    press = torch.zeros_like(x)
    press[len(x) // 2:, 1] = -0.01
    solver = StretchingSolver(kind="two_level", eta=1.0, margin=2e-3, contact_stiffness=2.5e3).eval()
    body_index = torch.zeros(len(x), dtype=torch.int64)
    with torch.no_grad():
        held, left = (solver(x, replace(cloth, layers=order), f_hat=press, steps=30, bodies=bodies,
                             body_index=body_index) for order in (follows, fixed))
    assert float(separation(held).min()) > 0.9e-3
    assert float(separation(left).min()) < -1e-3


def test_the_measured_energy_completes_the_layer_pairs_where_the_pieces_are():
    """`physics.energy.drape_energies` measures a following layer order with the pairs found at x:
    an outer sheet 0.5 mm over an inner one (authored 6 mm apart, gap 4 mm) and no template pair
    has a layer term of ½ k (3.5 mm)² per pair; without what completes the pairs, none."""
    from physdrape.physics.energy import drape_energies
    from physdrape.physics.layers import follow_pairs

    n = 6
    inner, faces = _sheet(n, 0.05, [0.0, 0.0, 0.0])
    outer, _ = _sheet(n, 0.05, [0.0, 0.006, 0.0])
    batch = GarmentBatch.pack([Garment.from_mesh(torch.cat([inner, outer]), torch.cat([faces, faces + n * n]),
                                                 dtype=torch.float64)])
    layers = _sheets_order(batch.rest, batch.faces, n)
    x = batch.rest.clone()
    x[n * n:, 1] = 5e-4
    verts = torch.tensor([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64) * 0.01 + 5.0
    bodies = BodySurface(verts, torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))  # far: no contact
    body_index = torch.zeros(2 * n * n, dtype=torch.int64)

    def layer_term(order):
        cloth = replace(Cloth.build(batch), layers=order)
        return float(drape_energies(x, cloth, bodies, body_index, contact_stiffness=1.0, margin=0.0)["layer"][0])

    pairs, _ = follow_pairs(x, layers)
    assert len(pairs) >= n * n
    assert layer_term(layers) == pytest.approx(len(pairs) * 0.5 * 1000.0 * 3.5e-3 ** 2, rel=1e-9)
    assert layer_term(replace(layers, piece=None)) == 0.0


def test_a_caller_sets_the_layer_pairs_tangential_share(sheet):
    """`links(cloth, slide=β)`: a layer pair's block k (n nᵀ + β (I − n nᵀ)); β = 0 is the layer
    energy's own block k n nᵀ of an active pair, and the default is `LAYER_SLIDE_DAMPING`."""
    from physdrape.physics.forces import LAYER_SLIDE_DAMPING, extra_blocks, links

    x = deformed(sheet, seed=5)
    layers = make_layers(sheet, x, 5, count=6, active=True)
    cloth = replace(Cloth.build(sheet), layers=layers)
    free = links(cloth, slide=0.0)
    torch.testing.assert_close(free.blocks, layer_pair_blocks(x, layers))
    n = layers.normal
    across = torch.eye(3, dtype=n.dtype) - n[:, :, None] * n[:, None, :]
    for beta in (None, 0.3):
        tied = links(cloth, slide=beta)
        expected = LAYER_SLIDE_DAMPING if beta is None else beta
        torch.testing.assert_close(tied.blocks - free.blocks, expected * layers.stiffness[:, None, None] * across)
    # the vertex blocks of the preconditioner's local part take the same share
    difference = extra_blocks(cloth, slide=0.3) - extra_blocks(cloth, slide=0.0)
    ends = torch.zeros(cloth.num_verts, 3, 3, dtype=n.dtype).index_add_(
        0, layers.pairs.reshape(-1), (0.3 * layers.stiffness[:, None, None] * across).repeat_interleave(2, dim=0))
    torch.testing.assert_close(difference, ends)


def test_a_layer_pairs_preconditioner_block_acts_within_its_reach(sheet):
    """`layer_link_weights`: every stitch, and the layer pairs whose outer vertex lies less than
    gap + `LAYER_LINK_REACH` outside the inner one, weigh 1, the pairs farther apart 0 (their
    energy is zero there); `links` and `extra_blocks` scale each link's block by its weight."""
    from test_stitches import make_stitches

    from physdrape.physics.forces import LAYER_LINK_REACH, extra_blocks, layer_link_weights, links

    x = deformed(sheet, seed=5)
    touching, apart = make_layers(sheet, x, 5, count=6), make_layers(sheet, x, 6, count=6, active=False)
    layers = replace(touching, pairs=torch.cat([touching.pairs, apart.pairs]),
                     normal=torch.cat([touching.normal, apart.normal]), gap=torch.cat([touching.gap, apart.gap]),
                     stiffness=torch.cat([touching.stiffness, apart.stiffness]))
    stitches = make_stitches(sheet, x, 6, count=4)
    cloth = replace(Cloth.build(sheet), stitches=stitches, layers=layers)
    weight = layer_link_weights(cloth, x)
    assert LAYER_LINK_REACH < 0.01  # `make_layers` puts the inactive pairs 1 cm beyond their gap
    assert weight.tolist() == [1.0] * 4 + [1.0] * 6 + [0.0] * 6
    assert layer_link_weights(cloth, x, reach=0.02).tolist() == [1.0] * 16
    assert layer_link_weights(replace(cloth, layers=None), x) is None
    torch.testing.assert_close(links(cloth, weight=weight).blocks, links(cloth).blocks * weight[:, None, None])
    kept = replace(cloth, layers=replace(layers, pairs=layers.pairs[:6], normal=layers.normal[:6], gap=layers.gap[:6],
                                         stiffness=layers.stiffness[:6]))
    torch.testing.assert_close(extra_blocks(cloth, weight=weight), extra_blocks(kept))
