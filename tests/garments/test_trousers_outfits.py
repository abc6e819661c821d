"""Procedural trousers, shorts and outfits (a top over trousers), and the catalogue of every
procedural garment by name."""

import numpy as np
import pytest

from physdrape.garments import catalogue
from physdrape.garments.body_fields import leg_fields
from physdrape.garments.generator import GarmentCategory, generate_garment, sample_params
from physdrape.garments.layering import layer_pairs
from physdrape.garments.outfits import LAYER_GAP, generate_valid_outfit, sample_outfit_params
from physdrape.garments.pieces import garment_parts
from physdrape.garments.trousers import (
    TrousersKind,
    TrousersParams,
    generate_trousers,
    generate_valid_trousers,
    sample_trousers_params,
)
from physdrape.garments.validate import validate_garment
from physdrape.geometry.topology import boundary_loops, connected_components

pytestmark = pytest.mark.anny


@pytest.fixture(scope="module")
def pairs_of_each_kind():
    return {k: generate_valid_trousers(k, 11)[0] for k in TrousersKind}


@pytest.fixture(scope="module")
def outfit():
    """An outfit whose top reaches over the waistband (a T-shirt or long sleeves)."""
    seed = next(s for s in range(50) if sample_outfit_params(s).top.category in
                (GarmentCategory.TSHIRT, GarmentCategory.LONGSLEEVE))
    return generate_valid_outfit(seed)[0]


def test_catalogue_names_every_generator():
    assert catalogue.TOPS == tuple(c.value for c in GarmentCategory)
    assert catalogue.LOWER == tuple(k.value for k in TrousersKind)
    with pytest.raises(ValueError, match="unknown garment category 'skirt'"):
        catalogue.generate_valid("skirt", 0)


def test_trousers_are_valid_tubes_ending_at_their_leg_length(pairs_of_each_kind, body):
    lf = leg_fields(body)
    for kind, g in pairs_of_each_kind.items():
        report = validate_garment(g.verts, g.faces, name=g.name, body=(body.verts, body.faces))
        assert report.ok, str(report)
        assert len(np.unique(connected_components(g.num_verts, g.faces))) == 1
        loops = boundary_loops(g.faces)
        assert len(loops) == 3, kind  # the waistband and two leg openings
        # the leg openings lie where the legs end along the hip→ankle axis
        _, closest, _ = lf.query(g.verts)
        k = np.argmin(np.linalg.norm(body.verts[None] - closest[:, None], axis=2), axis=1)
        legs = sorted(loops, key=lambda loop: g.verts[loop, 1].mean())[:2]
        for loop in legs:
            assert abs(np.median(lf.t[k[loop]]) - g.params.leg_length) < 0.03, kind
        # the waistband at the waistline, nothing above it
        assert g.verts[:, 1].max() < g.params.waist_height + 0.03


def test_trousers_are_deterministic_and_params_round_trip():
    p = sample_trousers_params("shorts", 3)
    assert p == sample_trousers_params(TrousersKind.SHORTS, 3) != sample_trousers_params("shorts", 4)
    assert TrousersParams.from_dict(p.to_dict()).to_dict() == p.to_dict()
    a, b = generate_trousers(p), generate_trousers(p)
    assert np.array_equal(a.verts, b.verts) and np.array_equal(a.faces, b.faces)


def test_clearance_floor_holds_the_garment_off_the_body(body):
    p = sample_params("tshirt", 5)
    g = generate_garment(p, clearance_floor=lambda points: np.full(len(points), 0.05))
    d, _, _ = leg_fields(body).query(g.verts)
    free, _, _ = leg_fields(body).query(generate_garment(p).verts)
    assert np.median(free) < 0.03 and np.percentile(free, 5) < 0.02  # what the floor changes
    # (the openings' smoothing pulls a few of their vertices in)
    assert np.median(d) > 0.05 - 1e-3 and np.percentile(d, 5) > 0.04 and d.min() > 0.02


def test_outfit_is_a_top_over_trousers(outfit, body):
    report = validate_garment(outfit.verts, outfit.faces, name=outfit.name, body=(body.verts, body.faces))
    assert report.ok, str(report)  # neither piece crosses the other or the body
    parts = garment_parts(outfit.verts, outfit.faces)
    assert parts.num_pieces == 2 and parts.lower == 0  # the trousers' vertices come first
    assert parts.waistband is not None and parts.hem is not None
    lp = layer_pairs(outfit.verts, parts.piece, body.verts, body.faces)
    assert len(lp.pairs) > 0
    assert lp.over[1, 0] and not lp.over[0, 1]  # the top lies over the trousers
    # where the top covers the waistband it keeps at least the layer gap over it
    d, _, _ = leg_fields(body).query(outfit.verts)
    outer, inner = lp.pairs[:, 0], lp.pairs[:, 1]
    close = np.linalg.norm(outfit.verts[outer] - outfit.verts[inner], axis=1) < 0.01
    assert close.any()
    assert (d[outer[close]] - d[inner[close]]).min() > 0.5 * LAYER_GAP


def test_outfit_params_round_trip_and_spec_names_it():
    from physdrape.api.specs import GARMENT_CATEGORIES, is_generated
    from physdrape.garments.outfits import OutfitParams

    p = sample_outfit_params(4)
    assert OutfitParams.from_dict(p.to_dict()).to_dict() == p.to_dict()
    assert set(GARMENT_CATEGORIES) == set(catalogue.CATEGORIES)
    assert is_generated("outfit:4") and is_generated("capri:2") and not is_generated("skirt:1")
