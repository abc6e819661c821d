"""Where a user's garment sits: its unit (`units=`) and its place on the canonical body
(detached garments are refused unless `allow_detached=True`), on the tiny test model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physdrape.api import GARMENT_CATEGORIES, DrapeError, DrapeWarning, fit_garment
from physdrape.api.placement import SURROUND_MAX_GAP_DEG, TOUCH_DISTANCE, attachment

MAKEHUMAN_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "makehuman_cc0"
MHCLO_FILES = sorted(MAKEHUMAN_DIR.glob("*/*.mhclo")) if MAKEHUMAN_DIR.is_dir() else []
#: A 10 cm triangle floating 12 cm in front of and beside the left hip of the canonical body.
FLOATING_TRIANGLE = (np.array([0.3, -0.05, 0.3]) + np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]]),
                     np.array([[0, 1, 2]]))


def floating_patch() -> tuple[np.ndarray, np.ndarray]:
    """A 10 cm square of 8 triangles in the floating triangle's place."""
    xs = np.linspace(0.0, 0.1, 3)
    verts = np.array([[0.3 + x, -0.05 + y, 0.3] for y in xs for x in xs])
    faces = [[a, a + 1, a + 3] for a in (0, 1, 3, 4)] + [[a + 1, a + 4, a + 3] for a in (0, 1, 3, 4)]
    return verts, np.array(faces)


@pytest.fixture(scope="module")
def tee():
    from physdrape.garments import default_garment

    g = default_garment()
    return np.asarray(g.verts, np.float64), np.asarray(g.faces, np.int64)


@pytest.mark.parametrize(("units", "factor"), [("cm", 100.0), ("mm", 1000.0)])
def test_garment_in_other_units_drapes_like_the_metre_garment(draper, tee, units, factor):
    verts, faces = tee
    [metres] = draper.drape((verts, faces))
    [other] = draper.drape((verts * factor, faces), units=units)
    np.testing.assert_allclose(other.verts, metres.verts, atol=1e-5)
    assert draper.garment((verts * factor, faces), units=units).verts == pytest.approx(verts, abs=1e-12)


@pytest.mark.parametrize(("factor", "units", "advice"), [
    (100.0, "m", 'looks like centimetres: pass units="cm"'),
    (10.0, "m", 'looks like decimetres: pass units="dm"'),
    (1000.0, "m", 'looks like millimetres: pass units="mm"'),
    (1000.0, "cm", 'looks like millimetres: pass units="mm"'),
    (1.0, "cm", 'too small for a garment.*looks like metres: pass units="m"'),
    (100.0, "mm", 'too small for a garment.*looks like centimetres: pass units="cm"'),
])
def test_a_garment_in_the_wrong_unit_names_the_unit_to_give(draper, tee, factor, units, advice):
    verts, faces = tee
    with pytest.raises(DrapeError, match=advice):
        draper.drape((verts * factor, faces), units=units)


def test_unknown_units_are_refused(draper):
    with pytest.raises(DrapeError, match="units must be one of m, dm, cm, mm"):
        draper.drape("default", units="inch")


def test_fit_reads_other_units_and_a_unit_scale_names_units(anny_body, tee, tmp_path):
    from physdrape.geometry.mesh import write_mesh

    verts, faces = tee
    path = tmp_path / "tee_dm.obj"
    write_mesh(path, verts * 10.0, faces)
    result = fit_garment(path, units="dm", iters=0, body=anny_body)
    assert result.units == "dm" and np.abs(result.verts - verts).mean() < 0.01
    with pytest.raises(DrapeError, match='units="dm"'):
        fit_garment(path, body=anny_body)
    with pytest.raises(DrapeError, match='converts decimetres to metres.*units="dm"'):
        fit_garment(path, scale=0.1, body=anny_body)


@pytest.mark.parametrize("spec", ["default"] + [f"{c}:{s}" for c in GARMENT_CATEGORIES for s in (0, 1)])
def test_bundled_and_generated_garments_hang_on_the_body(draper, spec):
    template = draper.garment(spec)
    assert draper.detached(template) is None
    nearest, gap = attachment(template.verts, *draper._canonical["anny"])
    assert nearest <= TOUCH_DISTANCE or gap <= SURROUND_MAX_GAP_DEG


@pytest.mark.skipif(not MHCLO_FILES, reason=f"no MakeHuman .mhclo garments in {MAKEHUMAN_DIR}")
@pytest.mark.parametrize("path", MHCLO_FILES, ids=[p.stem for p in MHCLO_FILES])
def test_makehuman_garments_hang_on_the_body(draper, path):
    assert draper.detached(draper.garment(str(path))) is None


def test_a_detached_garment_is_refused_unless_allowed(draper, tee):
    with pytest.raises(DrapeError, match=r"neither touches nor surrounds the body: its nearest vertex is 0\.1\d* m"
                                         r".*canonical body \(Anny.*allow_detached=True"):
        draper.drape(FLOATING_TRIANGLE)
    verts, faces = tee
    with pytest.raises(DrapeError, match="neither touches nor surrounds"):
        draper.drape((verts + [1.0, 0.0, 0.0], faces))  # the T-shirt a metre to the side
    with pytest.raises(DrapeError, match="neither touches nor surrounds"):
        draper.drape(floating_patch())
    with pytest.warns(DrapeWarning, match="neither touches nor surrounds.*draped anyway, as allowed"):
        [res] = draper.drape(floating_patch(), allow_detached=True)
    assert np.isfinite(res.verts).all()
