"""Φ per garment in one launch (`physics.potential`) against its terms composed from the per-element
kernels and torch (float64), on packed batches, with and without planes, external forces, ties; and
the force and blocks of `GarmentPotential.local_terms` against the per-term kernels and the
majorant's torch twin."""

from dataclasses import replace

import pytest
import torch
from device_params import DEVICES
from majorant_reference import vertex_blocks as reference_vertex_blocks

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet, open_cylinder
from physdrape.physics import Cloth, Material
from physdrape.physics.contact import (
    contact_energy,
    contact_samples,
    garment_energy,
    plane_contact_blocks,
    plane_contact_forces,
    plane_distance,
)
from physdrape.physics.forces import internal_energy, internal_forces, tie_forces
from physdrape.physics.layers import LayerOrder
from physdrape.physics.potential import GarmentPotential, _garment_parts
from physdrape.physics.stitches import Stitches

STIFFNESS, MARGIN, BAND = 2.5e3, 2e-3, 5e-3


def _case(sheet_cells=(12, 10), seed=0):
    sheet = Garment.from_mesh(*grid_sheet(*sheet_cells, width=0.4, height=0.3), name="sheet", dtype=torch.float64)
    tube = Garment.from_mesh(*open_cylinder(6, 14, radius=0.12, length=0.3), name="tube", dtype=torch.float64)
    batch = GarmentBatch.pack([sheet, tube, sheet])
    cloth = Cloth.build(batch, [Material(), Material(density=0.3), Material(k_bend=3e-5)])
    gen = torch.Generator().manual_seed(seed)
    x = batch.rest * 1.05 + 3e-3 * torch.randn(batch.rest.shape, generator=gen, dtype=torch.float64)
    samples = contact_samples(x, cloth.faces)
    normal = torch.nn.functional.normalize(torch.randn(samples.shape, generator=gen, dtype=torch.float64), dim=-1)
    depth = (4 * MARGIN) * torch.rand(samples.shape[0], generator=gen, dtype=torch.float64) - MARGIN  # some in contact
    closest = samples - depth[:, None] * normal
    external = 0.01 * torch.randn(x.shape, generator=gen, dtype=torch.float64)
    return batch, cloth, x, (closest, normal), external


def _potential(x, cloth, *, planes, external):
    potential = GarmentPotential(cloth, external=external, stiffness=STIFFNESS, margin=MARGIN)
    potential.hold(planes)
    return potential(x)


def _composed(x, cloth, planes, external):
    phi = internal_energy(x, cloth)
    if planes is not None:
        d = plane_distance(x, cloth.faces, *planes)
        phi = phi + garment_energy(contact_energy(d, stiffness=STIFFNESS, margin=MARGIN), cloth)
    if external is not None:
        phi = phi - cloth.sum_per_garment((external * x).sum(-1), cloth.vert_garment)
    return phi


def _tied(cloth, batch):
    gen = torch.Generator().manual_seed(3)
    first = batch.garments[0].num_verts
    stitched = torch.randperm(first, generator=gen)[:16].reshape(8, 2)
    layered = first + torch.randperm(batch.garments[1].num_verts, generator=gen)[:20].reshape(10, 2)
    normal = torch.nn.functional.normalize(torch.randn(10, 3, generator=gen, dtype=torch.float64), dim=-1)
    return replace(cloth, stitches=Stitches(stitched, torch.full((8,), 0.01, dtype=torch.float64),
                                            torch.full((8,), 200.0, dtype=torch.float64)),
                   layers=LayerOrder.build(layered, normal))


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_planes", [True, False], ids=["planes", "no_planes"])
@pytest.mark.parametrize("with_external", [True, False], ids=["external", "no_external"])
def test_matches_the_composed_terms(device, with_planes, with_external):
    _batch, cloth, x, planes, external = _case()
    planes = planes if with_planes else None
    external = external if with_external else None
    expected = _composed(x, cloth, planes, external)
    on = cloth.to(device=device)
    got = _potential(x.to(device), on, planes=None if planes is None else tuple(p.to(device) for p in planes),
                     external=None if external is None else external.to(device))
    assert got.dtype == torch.float64 and got.shape == (3,)
    torch.testing.assert_close(got.cpu(), expected, rtol=1e-12, atol=1e-15)
    if with_planes:  # the contact term is not negligible in the comparison
        d = plane_distance(x, cloth.faces, *planes)
        assert bool((d < MARGIN).any())


def test_ties_and_float32_positions():
    batch, cloth, x, planes, external = _case()
    tied = _tied(cloth, batch)
    expected = _composed(x, tied, planes, external)
    got = _potential(x, tied, planes=planes, external=external)
    torch.testing.assert_close(got, expected, rtol=1e-12, atol=1e-15)
    assert not torch.allclose(expected, _composed(x, cloth, planes, external))  # the ties count
    # float32 positions: float64 arithmetic on the float32 values
    x32 = x.float()
    got32 = _potential(x32, cloth, planes=planes, external=external)
    torch.testing.assert_close(got32, _composed(x32.double(), cloth, planes, external), rtol=1e-12, atol=1e-15)


def test_dropping_the_external_force_gives_the_potential_without_it():
    """After `drop_external` (the solver's steps past f̂), Φ and the local terms are those of a
    potential built without the external force, to the bit, and the caller's force is untouched."""
    _, cloth, x, planes, external = _case()
    given = external.clone()
    potential = GarmentPotential(cloth, external=external, stiffness=STIFFNESS, margin=MARGIN, band=BAND)
    without = GarmentPotential(cloth, stiffness=STIFFNESS, margin=MARGIN, band=BAND)
    for p in (potential, without):
        p.hold(planes)
    assert not torch.equal(potential(x), without(x))
    potential.local_terms(x)  # launches recorded with the force in
    potential.drop_external()
    assert torch.equal(potential(x), without(x))
    dropped, plain = potential.local_terms(x), without.local_terms(x)
    for field in ("force", "blocks", "contact"):
        assert torch.equal(getattr(dropped, field), getattr(plain, field)), field
    assert torch.equal(external, given)


def test_threads_split_by_garment_same_totals():
    """Two torch threads: the launch splits between whole garments and gives the one-thread totals."""
    _, cloth, x, planes, external = _case(sheet_cells=(40, 40))
    potential = GarmentPotential(cloth, external=external, stiffness=STIFFNESS, margin=MARGIN)
    potential.hold(planes)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = potential(x)
        torch.set_num_threads(2)
        parts = _garment_parts(cloth, 2)
        two = potential(x)
    finally:
        torch.set_num_threads(before)
    assert len(parts) == 2
    # the parts cover every face, hinge and vertex once, garment by garment
    for k, total in ((0, cloth.faces.shape[0]), (2, cloth.hinges.shape[0]), (4, cloth.num_verts)):
        assert parts[0][k] == 0 and parts[0][k + 1] == parts[1][k] and parts[1][k + 1] == total
    assert torch.equal(one, two)
    torch.testing.assert_close(one, _composed(x, cloth, planes, external), rtol=1e-12, atol=1e-15)


def test_new_positions_and_new_planes():
    """The recorded launch reads each call's positions and, after `hold`, the new planes (copied:
    the caller may change its tensors afterwards)."""
    _, cloth, x, planes, external = _case()
    potential = GarmentPotential(cloth, external=external, stiffness=STIFFNESS, margin=MARGIN)
    potential.hold(planes)
    first = potential(x)
    moved = x + 1e-3
    torch.testing.assert_close(potential(moved), _composed(moved, cloth, planes, external), rtol=1e-12, atol=1e-15)
    shifted = (planes[0] + 2e-3 * planes[1], planes[1])  # every plane 2 mm further out: more contact
    potential.hold(shifted)
    torch.testing.assert_close(potential(x), _composed(x, cloth, shifted, external), rtol=1e-12, atol=1e-15)
    assert bool((potential(x) > first).all())
    potential.hold(None)
    torch.testing.assert_close(potential(x), _composed(x, cloth, None, external), rtol=1e-12, atol=1e-15)
    potential.hold(planes)  # held again after none: the contact is back
    torch.testing.assert_close(potential(x), first, rtol=1e-12, atol=1e-15)
    held = planes[0].clone()
    potential.hold((held, planes[1]))
    held += 5e-3 * planes[1]  # the caller's tensor changes after hold: the potential holds its own copy
    torch.testing.assert_close(potential(x), first, rtol=1e-12, atol=1e-15)


def test_bad_shapes_are_refused():
    _, cloth, x, planes, external = _case()
    potential = GarmentPotential(cloth, stiffness=STIFFNESS, margin=MARGIN)
    with pytest.raises(ValueError, match="packed positions"):
        potential(x[:-1])
    with pytest.raises(ValueError, match="the planes must have shape"):
        potential.hold((planes[0][:-1], planes[1][:-1]))
    with pytest.raises(ValueError, match="a force per vertex"):
        GarmentPotential(cloth, external=external[:-1])


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("with_planes", [True, False], ids=["planes", "no_planes"])
@pytest.mark.parametrize("with_external", [True, False], ids=["external", "no_external"])
def test_local_terms_are_the_force_and_blocks_of_each_term(device, with_planes, with_external):
    """One launch gives the force of the per-term kernels (internal forces without the ties, the
    contact on the held planes, the external force), the majorant's vertex blocks (its torch twin)
    and the contact's band blocks; on a second set of planes, the same again."""
    batch, cloth, x, planes, external = _case()
    tied = _tied(cloth, batch)  # the ties' forces are the caller's: not in the local terms
    on = tied.to(device=device)
    potential = GarmentPotential(on, external=None if not with_external else external.to(device),
                                 stiffness=STIFFNESS, margin=MARGIN, band=BAND)
    for shift in (0.0, 2e-3):
        held = (planes[0] + shift * planes[1], planes[1])
        potential.hold(tuple(p.to(device) for p in held) if with_planes else None)
        terms = potential.local_terms(x.to(device))
        want = internal_forces(x, tied) - tie_forces(x, tied)
        want_contact = torch.zeros(x.shape[0], 3, 3, dtype=torch.float64)
        if with_planes:
            want = want + plane_contact_forces(x, cloth.faces, *held, stiffness=STIFFNESS, margin=MARGIN)
            want_contact = plane_contact_blocks(x, cloth.faces, *held, stiffness=STIFFNESS, margin=MARGIN, band=BAND)
            assert want_contact.abs().amax() > 0
        if with_external:
            want = want + external
        scale = want.abs().amax()
        torch.testing.assert_close(terms.force.cpu(), want, rtol=1e-10, atol=1e-12 * scale)
        blocks = reference_vertex_blocks(x, cloth)
        torch.testing.assert_close(terms.blocks.cpu(), blocks, rtol=1e-10, atol=1e-12 * blocks.abs().amax())
        torch.testing.assert_close(terms.contact.cpu(), want_contact, rtol=1e-10, atol=1e-12 * (1 + want_contact.abs().amax()))
        assert terms.compliance is None
        # with extra blocks and a floor: the contact carries the extra, the compliance inverts blocks + contact
        extra = 50.0 * torch.eye(3, dtype=torch.float64).expand(x.shape[0], 3, 3).clone()
        floored = potential.local_terms(x.to(device), extra=extra.to(device), rel=1e-6, tiny=1e-300)
        torch.testing.assert_close(floored.contact.cpu(), want_contact + extra, rtol=1e-10,
                                   atol=1e-12 * (1 + want_contact.abs().amax()))
        k = blocks + want_contact + extra
        k = k + 1e-6 * k.diagonal(dim1=-2, dim2=-1).sum(-1)[:, None, None] * torch.eye(3, dtype=torch.float64)
        torch.testing.assert_close(floored.compliance.cpu(), torch.linalg.inv(k), rtol=1e-8, atol=1e-12)


@pytest.mark.parametrize("device", DEVICES)
def test_local_terms_with_vertex_bands_add_the_depth_eps_block_where_a_vertex_is_within_its_band(device):
    """vertex_band: a vertex's own sample beyond the band but within its entry gets the block of
    depth ε, 6 k_c ε n nᵀ, on top of the band's blocks; the force and the centroids' blocks are
    those without; the same launch without vertex bands again gives the band's blocks alone."""
    batch, cloth, x, planes, _ = _case()
    on = cloth.to(device=device)
    potential = GarmentPotential(on, stiffness=STIFFNESS, margin=MARGIN, band=BAND)
    potential.hold(tuple(p.to(device) for p in planes))
    plain = potential.local_terms(x.to(device))
    plain_force, plain_contact = plain.force.cpu().clone(), plain.contact.cpu().clone()
    gen = torch.Generator().manual_seed(5)
    bands = BAND + 2e-2 * torch.rand(x.shape[0], generator=gen, dtype=torch.float64)
    banded = potential.local_terms(x.to(device), vertex_band=bands.to(device))
    v = x.shape[0]
    distance = ((x - planes[0][:v]) * planes[1][:v]).sum(-1)
    within = (distance >= BAND) & (distance < bands)
    assert within.any() and (distance >= bands).any()
    n = planes[1][:v]
    added = 6.0 * STIFFNESS * MARGIN * within[:, None, None] * n[:, :, None] * n[:, None, :]
    torch.testing.assert_close(banded.force.cpu(), plain_force, rtol=0, atol=0)
    torch.testing.assert_close(banded.contact.cpu(), plain_contact + added, rtol=1e-12,
                               atol=1e-12 * plain_contact.abs().amax())
    torch.testing.assert_close(potential.local_terms(x.to(device)).contact.cpu(), plain_contact, rtol=0, atol=0)


def test_local_terms_with_pair_blocks_are_the_same_terms_plus_the_majorants_pair_blocks():
    """Asked for a coarse space's pair layout, the local terms' launch also forms the strain
    majorant's pair blocks (`majorant.pair_blocks`), and the other terms are those without it;
    the layout's launch is kept beside the plain one (one thread and two: split by garment)."""
    from physdrape.physics.coarse_space import CoarseSpace
    from physdrape.physics.majorant import pair_blocks

    _, cloth, x, planes, external = _case()
    potential = GarmentPotential(cloth, external=external, stiffness=STIFFNESS, margin=MARGIN, band=BAND)
    potential.hold(planes)
    layout = CoarseSpace(cloth).pair_layout
    potential(x)  # Φ's launch recorded first: it stays beside the pair layout's
    before = torch.get_num_threads()
    try:
        for threads in (1, 2):
            torch.set_num_threads(threads)
            plain = potential.local_terms(x, rel=1e-6)
            plain = [t.clone() for t in (plain.force, plain.blocks, plain.contact, plain.compliance)]
            with_pairs = potential.local_terms(x, rel=1e-6, pairs=layout)
            for a, b in zip(plain, (with_pairs.force, with_pairs.blocks, with_pairs.contact, with_pairs.compliance)):
                assert torch.equal(a, b)
            want = pair_blocks(x, cloth, *layout)
            assert with_pairs.pairs.shape == (layout[1], 3, 3) and want.abs().amax() > 0
            torch.testing.assert_close(with_pairs.pairs, want, rtol=1e-12, atol=1e-12 * float(want.abs().amax()))
            assert potential.local_terms(x, rel=1e-6).pairs is None
        other = CoarseSpace(cloth, levels=1).pair_layout  # another layout: its own buffer and launches
        torch.testing.assert_close(potential.local_terms(x, pairs=other).pairs, pair_blocks(x, cloth, *other),
                                   rtol=1e-12, atol=1e-12 * float(want.abs().amax()))
    finally:
        torch.set_num_threads(before)


def test_local_terms_split_by_garment_same_terms():
    """Two torch threads: the local terms' launch splits between whole garments, same sums."""
    _, cloth, x, planes, external = _case(sheet_cells=(40, 40))
    potential = GarmentPotential(cloth, external=external, stiffness=STIFFNESS, margin=MARGIN, band=BAND)
    potential.hold(planes)
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = potential.local_terms(x)
        one = type(one)(*(t.clone() for t in (one.force, one.blocks, one.contact)))  # buffers the next call reuses
        torch.set_num_threads(2)
        two = potential.local_terms(x)
    finally:
        torch.set_num_threads(before)
    for a, b in zip((one.force, one.blocks, one.contact), (two.force, two.blocks, two.contact)):
        torch.testing.assert_close(a, b, rtol=1e-13, atol=1e-15 * (1 + a.abs().amax()))
