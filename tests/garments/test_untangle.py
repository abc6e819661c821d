"""Untangling self-intersecting garments (layered MakeHuman suits) and `fit_garment` on them."""

from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.geometry.intersections import (
    self_intersecting_faces,
    self_intersecting_pairs,
)

MAKEHUMAN_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0"
SUIT = MAKEHUMAN_DIR / "female_casualsuit01" / "female_casualsuit01.mhclo"
needs_suit = pytest.mark.skipif(not SUIT.is_file(), reason=f"MakeHuman CC0 suit not found at {SUIT}")


def test_pairs_of_two_crossing_triangles():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],             # in z = 0
                  [0.2, 0.2, -0.5], [0.2, 0.2, 0.5], [0.9, 0.9, 0.0],  # pierces it
                  [5, 5, 5], [6, 5, 5], [5, 6, 5]], float)      # far away
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    assert self_intersecting_pairs(v, f).tolist() == [[0, 1]]
    assert self_intersecting_faces(v, f).tolist() == [0, 1]
    v[3:6, 2] += 2.0  # moved apart
    assert self_intersecting_pairs(v, f).shape == (0, 2)
    assert self_intersecting_pairs(v, f[:0]).shape == (0, 2)


@pytest.fixture(scope="module")
def suit():
    from physdrape.garments import load_mhclo

    return load_mhclo(SUIT, resolve_margin=None), load_mhclo(SUIT)


@pytest.fixture(scope="module")
def anny_body():
    from physdrape.body.anny_body import get_anny_body

    anny = get_anny_body()
    return anny.canonical_verts(dtype=torch.float64).numpy(), anny.faces.numpy()


@needs_suit
def test_untangle_layered_suit(suit, anny_body):
    from physdrape.garments import validate_garment
    from physdrape.garments.untangle import untangle_garment

    raw, pushed = suit
    assert len(self_intersecting_faces(pushed.verts, pushed.faces)) > 0  # the top's hem through the trousers
    x, info = untangle_garment(pushed.verts, pushed.faces, *anny_body, margin=2e-3)
    assert info.faces_before > 0 and info.faces_after == 0
    report = validate_garment(x, pushed.faces, body=anny_body, margin=2e-3, require_clearance=True)
    assert report.ok, str(report)
    assert report.min_clearance >= 2e-3 - 1e-5
    disp = np.linalg.norm(x - raw.verts, axis=1)
    assert disp.max() < 0.03 and disp.mean() < 0.002  # local moves: the suit keeps its shape


@needs_suit
def test_fit_garment_mhclo_suit_is_valid():
    from physdrape.api import fit_garment
    from physdrape.garments import validate_garment

    result = fit_garment(SUIT, iters=3)
    assert result.ok, result.validation
    untangle = result.relax["untangle"]
    assert untangle["before_relax"]["self_intersecting_faces_before"] > 0
    assert "displacement_from_refit_m" in result.relax
    report = validate_garment(result.verts, result.faces, margin=2e-3, require_clearance=True)
    assert report.ok and len(report.self_intersecting_faces) == 0, str(report)


OBJ_SUIT = MAKEHUMAN_DIR / "female_casualsuit01" / "female_casualsuit01"
needs_obj_suit = pytest.mark.skipif(not OBJ_SUIT.with_suffix(".obj").is_file(),
                                    reason=f"MakeHuman CC0 suit not found at {OBJ_SUIT}.obj")


@needs_obj_suit
def test_fit_places_a_suit_obj_where_its_binding_puts_it():
    """The suit's raw .obj (decimetres, on MakeHuman's base body) is aligned within 1 cm of the
    translation that best matches its own .mhclo refit onto the canonical body (the top's
    highest point alone would put it 6 cm too high)."""
    from physdrape.api.fitting import _align_to_body
    from physdrape.body.anny_body import get_anny_body
    from physdrape.garments import load_mhclo
    from physdrape.geometry.mesh import read_mesh

    refit = load_mhclo(OBJ_SUIT.with_suffix(".mhclo"), target_edge=None, resolve_margin=None).verts
    verts = read_mesh(OBJ_SUIT.with_suffix(".obj"))[0] * 0.1
    best = refit.mean(0) - verts.mean(0)
    t = _align_to_body(verts, get_anny_body())
    assert np.linalg.norm(t - best) < 0.01, (t, best)


@needs_obj_suit
def test_fit_garment_obj_suit_in_decimetres_is_valid():
    from physdrape.api import fit_garment

    result = fit_garment(OBJ_SUIT.with_suffix(".obj"), units="dm", iters=3)
    assert result.ok, result.validation
    assert result.relax["layer_pairs"] > 0  # the top and trousers relax in their layer order
