"""The waistband grip through the pipeline and the Draper."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.api import DrapeError
from physdrape.garments.pieces import garment_parts
from physdrape.physics.grip import DEFAULT_GRIP_STIFFNESS
from physdrape.pipeline import Job

SUIT = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0" / "male_casualsuit04" / "male_casualsuit04.mhclo"
needs_suit = pytest.mark.skipif(not SUIT.is_file(), reason="the CC0 MakeHuman suits are not available")


@needs_suit
def test_pipeline_grips_the_waistband_strip_only(draper):
    pipeline = draper.pipeline("anny")
    suit, tee = draper.garment(str(SUIT)), draper.garment("default")
    body = draper.body("anny")
    state = body(draper.shape({"weight": 0.2}), body.rest_pose(1, dtype=torch.float64))
    material = draper.material(None)
    inp = pipeline.build([Job(tee, 0, material, grip=1e4), Job(suit, 0, material, grip=1e4)], state)
    grip = inp.cloth.grip
    assert grip is not None
    offset = int(inp.garments.vert_offsets[1])
    assert int(grip.index.min()) >= offset  # the tee has no waistband: nothing of it grips
    parts = garment_parts(suit.verts, suit.faces)
    local = grip.index.numpy() - offset
    assert set(parts.waistband.tolist()) <= set(local.tolist())
    assert np.all(parts.piece[local] == parts.lower)
    torch.testing.assert_close(grip.anchor, inp.x_init[grip.index])
    assert torch.allclose(grip.normal.norm(dim=-1), torch.ones(len(grip.index), dtype=grip.normal.dtype))
    assert pipeline.build([Job(suit, 0, material)], state).cloth.grip is None  # grip 0: none


@needs_suit
def test_draper_grip_holds_the_waistband_and_checks_its_value(draper):
    slim = {"weight": 0.1}
    [held] = draper.drape(str(SUIT), shape=slim, steps=8, layers="off")
    [loose] = draper.drape(str(SUIT), shape=slim, steps=8, grip=0, layers="off")  # the tee would hold it
    template = draper.garment(str(SUIT))
    band = garment_parts(template.verts, template.faces).waistband

    def drop(res):
        return float((res.x_init[band, 1] - res.verts[band, 1]).mean())

    assert drop(held) < drop(loose) - 5e-3, (drop(held), drop(loose))
    assert DEFAULT_GRIP_STIFFNESS > 0
    for bad in (-1.0, float("nan"), "tight", True):
        with pytest.raises(DrapeError, match="grip must be a stiffness"):
            draper.drape(str(SUIT), grip=bad)


def test_trousers_worn_alone_are_gripped_and_stay_on(draper):
    """A pair of trousers alone is a lower piece too: its waistband is gripped, so the trousers stay
    where they are worn instead of sliding down the legs (without the grip the waistband of
    trousers:0 falls about 20 cm in 15 steps)."""
    template = draper.garment("trousers:0")
    parts = garment_parts(template.verts, template.faces)
    assert parts.num_pieces == 1 and parts.lower == 0 and parts.waistband is not None
    assert template.verts[parts.waistband, 1].mean() > template.verts[:, 1].max() - 0.05  # the top opening
    assert garment_parts(draper.garment("default").verts, draper.garment("default").faces).lower is None

    def drop(res):
        return float((res.x_init[parts.waistband, 1] - res.verts[parts.waistband, 1]).mean())

    [held] = draper.drape("trousers:0", pose="stand", steps=8)
    [loose] = draper.drape("trousers:0", pose="stand", steps=8, grip=0)
    assert drop(held) < 5e-3 and drop(loose) > 5e-2, (drop(held), drop(loose))
