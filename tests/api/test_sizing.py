"""Sizing: a garment's rest shape fitted to the body's shape ("fit") or kept ("fixed")."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.api import DrapeError
from physdrape.garments.pieces import garment_parts
from physdrape.garments.sizing import MhcloSizer, Sizing, default_sizing
from physdrape.physics import Cloth, energy_terms
from physdrape.pipeline import Job

MAKEHUMAN_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0"
SUIT = MAKEHUMAN_DIR / "male_casualsuit04" / "male_casualsuit04.mhclo"
needs_suit = pytest.mark.skipif(not SUIT.is_file(), reason="the CC0 MakeHuman suits are not available")


def perimeter(x: np.ndarray, loop: np.ndarray) -> float:
    return float(np.linalg.norm(x[loop] - x[np.roll(loop, -1)], axis=1).sum())


def test_defaults_per_source():
    assert default_sizing(None) is Sizing.FIXED
    assert default_sizing(object()) is Sizing.FIT


@needs_suit
def test_mhclo_rest_is_the_template_on_the_canonical_body_and_follows_the_waist(draper):
    t = draper.garment(str(SUIT))
    assert isinstance(t.sizer, MhcloSizer)
    np.testing.assert_allclose(t.sizer.rest(None), t.verts, atol=1e-9)
    parts = garment_parts(t.verts, t.faces)
    girth = {w: perimeter(t.sizer.rest(draper.shape({"weight": w})), parts.waistband) for w in (0.1, 0.9)}
    canonical = perimeter(t.verts, parts.waistband)
    assert girth[0.1] < canonical - 0.015 and girth[0.9] > canonical + 0.025, (girth, canonical)


@needs_suit
def test_drape_sizing_fit_and_fixed(draper):
    heavy = {"weight": 0.9}
    # the layer order off: its push of the outer pieces over the inner ones at X_init would add
    # strain of its own to both
    [fit] = draper.drape(str(SUIT), shape=heavy, sizing="fit", steps=0, layers="off")
    [fixed] = draper.drape(str(SUIT), shape=heavy, sizing="fixed", steps=0, layers="off")
    [default] = draper.drape(str(SUIT), shape=heavy, steps=0, layers="off")
    np.testing.assert_array_equal(default.x_init, fit.x_init)  # .mhclo: fit by default
    assert np.abs(fit.x_init - fixed.x_init).max() > 5e-3
    # the fixed garment is held to the template's size on the heavy body: its X_init is stretched
    assert fixed.metrics["strain"] > 3 * fit.metrics["strain"], (fixed.metrics["strain"], fit.metrics["strain"])
    # on the canonical body both are the template
    [a], [b] = (draper.drape(str(SUIT), sizing=s, steps=0) for s in ("fit", "fixed"))
    np.testing.assert_allclose(a.x_init, b.x_init, atol=1e-6)
    with pytest.raises(DrapeError, match="sizing must be one of fit, fixed"):
        draper.drape(str(SUIT), sizing="loose")


def test_mesh_garment_fit_uses_the_transfer_shape_part(draper):
    [fixed] = draper.drape("default", shape={"weight": 0.9, "muscle": 0.8}, steps=0)  # meshes: fixed by default
    [fit] = draper.drape("default", shape={"weight": 0.9, "muscle": 0.8}, sizing="fit", steps=0)
    assert fixed.metrics["strain"] > 2 * fit.metrics["strain"], (fixed.metrics["strain"], fit.metrics["strain"])
    pipeline = draper.pipeline("anny")
    t = draper.garment("default")
    body = draper.body("anny")
    state = body(draper.shape({"weight": 0.9, "muscle": 0.8}), body.rest_pose(1, dtype=torch.float64))
    rest = pipeline.fitted_rest(t, state)
    # the fitted rest is the template moved by the transfer's shape part: at rest pose, X_init is that rest
    inp = pipeline.build([Job(t, 0, draper.material(None), rest=rest)], state)
    cloth = Cloth.build(pipeline.garment(t, rest).to(torch.float64))
    strain = energy_terms(inp.x_init.to(torch.float64), cloth)["strain"]
    assert float(strain) < 1e-3 * float(energy_terms(inp.x_init.to(torch.float64),
                                                     Cloth.build(pipeline.garment(t).to(torch.float64)))["strain"])
