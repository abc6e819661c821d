from pathlib import Path

import numpy as np
import pytest

from physdrape.garments import load_mhclo, read_mhclo, validate_garment
from physdrape.garments.mhclo import fit_mhclo
from physdrape.geometry.mesh import MeshError

MAKEHUMAN_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0"

pytestmark = pytest.mark.anny

MHCLO = sorted(MAKEHUMAN_DIR.glob("*/*.mhclo")) if MAKEHUMAN_DIR.is_dir() else []
needs_data = pytest.mark.skipif(not MHCLO, reason=f"MakeHuman CC0 clothes not found at {MAKEHUMAN_DIR}")


@needs_data
@pytest.mark.parametrize("path", MHCLO, ids=lambda p: p.stem)
def test_refit_cc0_garment_is_outside_the_default_body(path, body):
    g = load_mhclo(path)
    report = validate_garment(g.verts, g.faces, name=g.name, body=(body.verts, body.faces),
                              require_clearance=False, check_self_intersections=False)
    assert report.inside_area_fraction <= 0.01, str(report)
    assert report.extent < 2.0 and not len(report.non_manifold_edges)
    assert abs(report.mean_edge - 0.015) < 0.004  # remeshed from 1.4-3 cm edges


def triangle_quality(verts, faces):
    """4√3 · area / Σ edge² per face: 1 for an equilateral triangle, 0 for a flat one."""
    a, b, c = (verts[faces[:, i]] for i in range(3))
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    squares = ((b - a) ** 2).sum(1) + ((c - b) ** 2).sum(1) + ((a - c) ** 2).sum(1)
    return 4 * np.sqrt(3) * area / squares


@needs_data
@pytest.mark.parametrize("path", MHCLO, ids=lambda p: p.stem)
def test_worn_cc0_garment_has_no_slivers(path, body):
    # as `Draper.drape` loads an .mhclo: remeshed, pushed out of the body, its layers untangled;
    # a flat triangle in the rest shape (male_casualsuit05 had one folded over its neighbour, and
    # needles the untangling squeezed) is stretched without bound by any move of its far corner
    g = load_mhclo(path, untangle=True)
    assert triangle_quality(np.asarray(g.verts), np.asarray(g.faces)).min() > 0.05


@needs_data
def test_refit_follows_the_body(body):
    b = read_mhclo(MHCLO[0])
    assert b.ref_verts.shape == b.weights.shape == b.offsets.shape
    np.testing.assert_allclose(b.weights.sum(1), 1.0, atol=1e-3)
    import torch

    from physdrape.body.anny_body import get_anny_body

    anny = get_anny_body()
    with torch.no_grad():
        h = anny.hm08_verts(anny.default_shape(1, dtype=torch.float64))[0].numpy()
    x0 = fit_mhclo(b, h)
    # a rigid shift of the body shifts the garment; a uniform scale scales it (offsets too)
    np.testing.assert_allclose(fit_mhclo(b, h + [0.1, 0.2, 0.3]), x0 + [0.1, 0.2, 0.3], atol=1e-5)  # weights sum to 1 ± 1e-5
    np.testing.assert_allclose(fit_mhclo(b, 2 * h), 2 * x0, atol=1e-12)
    # every garment vertex sits within a few cm of the body surface (bound to its helpers)
    from physdrape.garments.numpy_geometry import BodyDistance

    d = BodyDistance(body.verts, body.faces)(x0)[0]
    assert np.percentile(np.abs(d), 95) < 0.05


def test_mhclo_errors(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        read_mhclo(tmp_path / "missing.mhclo")
    bad = tmp_path / "bad.mhclo"
    bad.write_text("name bad\nx_scale 1 2\n")
    with pytest.raises(MeshError, match="x_scale"):
        read_mhclo(bad)
    empty = tmp_path / "empty.mhclo"
    empty.write_text("name empty\nobj_file empty.obj\n")
    with pytest.raises(MeshError, match="no vertex binding"):
        read_mhclo(empty)
    two = tmp_path / "two.mhclo"
    two.write_text("obj_file two.obj\nverts 0\n1 2 3 0.2 0.3 0.5 0 0 0\n4\n")
    (tmp_path / "two.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(MeshError, match="do not belong together"):
        load_mhclo(two, hm08=np.zeros((19158, 3)))
