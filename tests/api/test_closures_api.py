"""Closures: overlapping panels tied by stitches through the pipeline and the Draper."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.api import DrapeError
from physdrape.pipeline import Job

JACKET = (Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0" / "male_casualsuit05"
          / "male_casualsuit05.mhclo")
needs_suit = pytest.mark.skipif(not JACKET.is_file(), reason="the CC0 MakeHuman suits are not available")


@needs_suit
def test_pipeline_stitches_the_overlapping_front(draper):
    pipeline = draper.pipeline("anny")
    suit = draper.garment(str(JACKET))
    pairs = pipeline.closure_pairs(suit)
    assert len(pairs) > 20
    front = suit.verts[pairs.reshape(-1)]
    assert np.all((front[:, 2] > 0) | (front[:, 1] > 0.5))  # the front panels and the layered collar
    assert np.all(np.abs(front[:, 0]) < 0.2)
    body = draper.body("anny")
    state = body(draper.shape(None), body.rest_pose(1, dtype=torch.float64))
    material = draper.material(None)
    inp = pipeline.build([Job(draper.garment("default"), 0, material), Job(suit, 0, material, stitches=pairs)], state)
    st = inp.cloth.stitches
    offset = int(inp.garments.vert_offsets[1])
    np.testing.assert_array_equal(st.pairs.numpy(), pairs + offset)
    rest = np.linalg.norm(suit.verts[pairs[:, 0]] - suit.verts[pairs[:, 1]], axis=1)
    np.testing.assert_allclose(st.rest.numpy(), rest, rtol=1e-5, atol=1e-7)
    assert pipeline.build([Job(suit, 0, material)], state).cloth.stitches is None


@needs_suit
def test_draper_closures_keep_the_front_closed_and_check_their_input(draper):
    shape = {"weight": 0.2}
    suit = draper.garment(str(JACKET))
    pairs = draper.pipeline("anny").closure_pairs(suit)

    def opening(res):
        d = np.linalg.norm(res.verts[pairs[:, 0]] - res.verts[pairs[:, 1]], axis=1)
        return float(np.clip(d - np.linalg.norm(suit.verts[pairs[:, 0]] - suit.verts[pairs[:, 1]], axis=1), 0, None).mean())

    [closed] = draper.drape(str(JACKET), shape=shape, steps=8)
    [given] = draper.drape(str(JACKET), shape=shape, steps=8, closures=pairs)
    [free] = draper.drape(str(JACKET), shape=shape, steps=8, closures="off")
    np.testing.assert_allclose(given.verts, closed.verts)
    assert opening(closed) < 0.5 * opening(free), (opening(closed), opening(free))
    for bad, match in (("buttons", "'auto', 'off'"), (np.zeros((3, 3), int), r"\(K, 2\) integer"),
                       ([[0, 0]], "to itself"), ([[0, 10**7]], r"must be in \[0, ")):
        with pytest.raises(DrapeError, match=match):
            draper.drape(str(JACKET), closures=bad)
