"""Untangling self-intersecting garments (layered MakeHuman suits) and `fit_garment` on them."""

from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.garments.intersections import self_intersecting_faces, self_intersecting_pairs

MAKEHUMAN_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0"
SUIT = MAKEHUMAN_DIR / "female_sportsuit01" / "female_sportsuit01.mhclo"
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
    assert len(self_intersecting_faces(pushed.verts, pushed.faces)) > 0  # top over trousers, creases
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
