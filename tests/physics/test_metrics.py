"""Metrics on hand-made cases with known answers."""

import numpy as np
import pytest
import torch
import trimesh

from physdrape.physics.metrics import b2g_percent, drape_metrics
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.proximity import BodySurface
from physdrape.physics import Cloth, Material, internal_forces

MAT = Material()


def box_body(dtype=torch.float64) -> BodySurface:
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))  # [-0.5, 0.5]³
    return BodySurface(torch.tensor(np.asarray(box.vertices), dtype=dtype), torch.tensor(np.asarray(box.faces)))


def sheet_at(x_from: float, y: float) -> Garment:
    verts, faces = grid_sheet(5, 11, width=1.0, height=0.4)
    verts += [x_from, y, -0.2]
    return Garment.from_mesh(verts, faces)


def test_garment_fully_outside_has_zero_b2g_and_no_close_vertices():
    batch = GarmentBatch.pack(sheet_at(0.0, 0.6))  # 10 cm above the box
    m = drape_metrics(batch.rest, batch, box_body(), batch.vert_garment)
    assert float(m.b2g_percent[0]) == 0.0
    assert float(m.close_percent[0]) == 0.0


def test_half_a_sheet_pushed_into_a_box_body():
    # x from 0 to 1 across the box face at x = 0.5 (a cell boundary): exactly half the area inside.
    batch = GarmentBatch.pack([sheet_at(0.0, 0.3), sheet_at(-0.25, 0.3), sheet_at(2.0, 0.0)])
    b2g = b2g_percent(batch.rest, batch, box_body(), torch.zeros_like(batch.vert_garment))  # one box for all
    torch.testing.assert_close(b2g, torch.tensor([50.0, 75.0, 0.0], dtype=torch.float64))


def test_energies_of_a_known_stretch_use_the_default_material():
    garment = sheet_at(0.0, 2.0)
    batch = GarmentBatch.pack(garment)
    s = 1.1
    x = batch.rest.clone()
    x[:, 0] = x[:, 0] * s  # uniaxial stretch along x: G_xx = (s² − 1)/2
    m = drape_metrics(x, batch, box_body(), batch.vert_garment)
    g = 0.5 * (s * s - 1)
    expected = MAT.thickness * 0.4 * (MAT.mu * g * g + 0.5 * MAT.lam * g * g)
    assert float(m.strain[0]) == pytest.approx(expected, rel=1e-10)
    assert float(m.bend[0]) == pytest.approx(0.0, abs=1e-20)
    # Far from the body every vertex is free: the residual is the mean |F_int| (stretch + gravity).
    assert float(m.residual_force[0]) > 0
    at_rest = drape_metrics(batch.rest, batch, box_body(), batch.vert_garment)
    # A flat sheet at rest feels only gravity: each vertex's force is exactly its weight.
    assert float(at_rest.residual_relative[0]) == pytest.approx(1.0, rel=1e-10)


def test_a_distance_bound_gives_the_same_metrics():
    """Sheets half inside the box, near it and far from it, with a bound from a query of them a
    few millimetres away: the same metrics (and inside flags) as querying everything."""
    from physdrape.geometry.distance_bound import DistanceBound
    from physdrape.physics.contact import contact_samples, query_samples
    from physdrape.physics.metrics import faces_inside

    batch = GarmentBatch.pack([sheet_at(0.0, 0.3), sheet_at(0.0, 0.5005), sheet_at(2.0, 0.0)])
    body, index = box_body(), torch.zeros_like(batch.vert_garment)
    x = batch.rest
    earlier = x + 3e-3 * torch.rand(x.shape, generator=torch.Generator().manual_seed(0), dtype=x.dtype)
    bound = DistanceBound.of(contact_samples(earlier, batch.faces),
                             query_samples(earlier, batch.faces, body, index).signed_distance)
    inside = faces_inside(x, batch, body, index)
    assert bool(inside.any()) and not bool(inside.all())
    assert torch.equal(faces_inside(x, batch, body, index, bound=bound), inside)
    want = drape_metrics(x, batch, body, index).as_dict()
    found = drape_metrics(x, batch, body, index, bound=bound)
    assert found.as_dict() == want and want["close_percent"][1] > 0
    # each vertex's residual relative to its weight, beside the per-garment means
    cloth = Cloth.build(batch)
    weight = cloth.mass * cloth.gravity[cloth.vert_garment].norm(dim=-1)
    torch.testing.assert_close(found.vertex_residual, internal_forces(x, cloth).norm(dim=-1) / weight, rtol=0, atol=0)
    assert "vertex_residual" not in want
