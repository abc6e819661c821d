import numpy as np
import pytest

from physdrape.garments import GarmentCategory, generate_garment, sample_params, validate_garment
from physdrape.garments.remesh import mean_edge_length
from physdrape.geometry.topology import boundary_loops, connected_components

pytestmark = pytest.mark.anny


def test_small_batch_passes_validation(small_batch, body):
    assert {g.params.category for g in small_batch} == set(GarmentCategory)
    for g in small_batch:
        report = validate_garment(g.verts, g.faces, name=g.name, body=(body.verts, body.faces))
        assert report.ok, str(report)
        assert report.min_clearance >= 2e-3 - 1e-5
        assert len(report.self_intersecting_faces) == 0
        assert report.inside_area_fraction == 0.0


def test_templates_look_like_tops(small_batch):
    for g in small_batch:
        assert 1500 <= g.num_verts <= 6000, (g.name, g.num_verts)
        assert g.verts.dtype == np.float64 and g.faces.dtype == np.int64
        assert len(np.unique(connected_components(g.num_verts, g.faces))) == 1
        # neck, hem and two sleeve ends / armholes; a disk with 3 holes: V - E + F = -2
        assert len(boundary_loops(g.faces)) == 4
        assert abs(mean_edge_length(g.verts, g.faces) - 0.015) < 0.003
        height = np.ptp(g.verts[:, 1])
        assert 0.2 < height < 0.8


def test_generator_is_deterministic():
    p = sample_params("tshirt", 7)
    assert p == sample_params(GarmentCategory.TSHIRT, 7)
    assert p != sample_params("tshirt", 8)
    a, b = generate_garment(p), generate_garment(p)
    assert np.array_equal(a.faces, b.faces)
    assert np.array_equal(a.verts, b.verts)


def test_parameters_change_the_garment():
    long = generate_garment(sample_params("longsleeve", 3))
    tank = generate_garment(sample_params("tanktop", 3))
    # long sleeves reach much further out along the arms than a sleeveless top
    assert np.abs(long.verts[:, 0]).max() > np.abs(tank.verts[:, 0]).max() + 0.1


def test_bundled_default_garment_is_valid(body):
    from physdrape.garments import default_garment

    g = default_garment()
    assert 1500 <= g.num_verts <= 6000
    report = validate_garment(g.verts, g.faces, name=g.name, body=(body.verts, body.faces))
    assert report.ok, str(report)
