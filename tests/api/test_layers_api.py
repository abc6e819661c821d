"""Layer order of a multi-piece garment through the pipeline and the Draper."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.api import DrapeError
from physdrape.garments.numpy_geometry import BodyDistance
from physdrape.garments.pieces import garment_parts
from physdrape.physics.layers import DEFAULT_LAYER_GAP, MIN_LAYER_GAP, layer_energy
from physdrape.pipeline import Job

SUIT = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0" / "male_casualsuit04" / "male_casualsuit04.mhclo"
needs_suit = pytest.mark.skipif(not SUIT.is_file(), reason="the CC0 MakeHuman suits are not available")


@needs_suit
def test_pipeline_layers_the_tee_over_the_trousers(draper):
    pipeline = draper.pipeline("anny")
    suit = draper.garment(str(SUIT))
    parts = garment_parts(suit.verts, suit.faces)
    pairs = pipeline.layer_pairs(suit)
    assert len(pairs) > 50
    assert np.all(parts.piece[pairs[:, 0]] != parts.piece[pairs[:, 1]])
    tee_outside = np.mean((parts.piece[pairs[:, 0]] != parts.lower) & (parts.piece[pairs[:, 1]] == parts.lower))
    assert tee_outside > 0.9, tee_outside  # the tee lies over the trousers (a few pairs at the edges differ)
    body = draper.body("anny")
    state = body(draper.shape({"weight": 0.8}), body.rest_pose(1, dtype=torch.float64))
    material = draper.material(None)
    inp = pipeline.build([Job(draper.garment("default"), 0, material, layers=True),
                          Job(suit, 0, material, layers=True)], state)
    layers = inp.cloth.layers
    offset = int(inp.garments.vert_offsets[1])
    np.testing.assert_array_equal(layers.pairs.numpy(), pairs + offset)  # the one-piece tee has none
    torch.testing.assert_close(layers.normal.norm(dim=-1), torch.ones(len(pairs), dtype=layers.normal.dtype))
    # each pair keeps the gap it has on the template, within [MIN_LAYER_GAP, DEFAULT_LAYER_GAP]
    d = BodyDistance(body.canonical_verts(dtype=torch.float64).numpy(), np.asarray(body.faces, np.int64))(suit.verts)[0]
    separation = d[pairs[:, 0]] - d[pairs[:, 1]]
    np.testing.assert_allclose(layers.gap.numpy(), np.clip(separation, MIN_LAYER_GAP, DEFAULT_LAYER_GAP))
    assert (layers.gap < DEFAULT_LAYER_GAP).any() and (layers.gap == DEFAULT_LAYER_GAP).any()
    # what completes the pairs where the pieces are: pieces (the tee's none), the suit's pieces as one
    # garment's, body distances on the template, the suit's faces
    assert layers.follows and layers.fixed is None
    assert bool((layers.piece[:offset] == -1).all())
    np.testing.assert_array_equal(layers.piece[offset:].numpy(), parts.piece)
    assert layers.together.tolist() == [[True, True], [True, True]]
    np.testing.assert_array_equal(layers.faces.numpy(), np.asarray(suit.faces) + offset)
    np.testing.assert_allclose(layers.depth[offset:].numpy(), d, atol=1e-6)
    # X_init starts with the outer piece pushed out over the inner one: the skinned pieces cross
    skinned = inp.x_init.clone()
    skinned[offset:] = pipeline.x_init(suit, state, 0).to(skinned.dtype)
    before, after = float(layer_energy(skinned, layers).sum()), float(layer_energy(inp.x_init, layers).sum())
    assert before > 1e-3 and after < 0.05 * before, (before, after)
    outer = torch.zeros(len(skinned), dtype=torch.bool)
    outer[layers.pairs[:, 0]] = True
    moved = (inp.x_init - skinned).norm(dim=-1) > 0
    assert bool(moved.any()) and not bool((moved & ~outer).any())  # only outer vertices, none of the tee's
    assert pipeline.build([Job(suit, 0, material)], state).cloth.layers is None


@needs_suit
def test_draper_layers_keep_the_pieces_apart(draper):
    from physdrape.geometry.intersections import self_intersecting_pairs

    suit = draper.garment(str(SUIT))
    piece = garment_parts(suit.verts, suit.faces).piece

    def crossings(res):
        pairs = self_intersecting_pairs(res.verts, suit.faces)
        owner = piece[suit.faces[:, 0]]
        return int((owner[pairs[:, 0]] != owner[pairs[:, 1]]).sum())

    shape = {"weight": 0.9}
    [layered] = draper.drape(str(SUIT), shape=shape, steps=8)
    [free] = draper.drape(str(SUIT), shape=shape, steps=8, layers="off")
    assert crossings(layered) < crossings(free), (crossings(layered), crossings(free))
    with pytest.raises(DrapeError, match="layers must be 'auto'"):
        draper.drape(str(SUIT), layers="outside")


@needs_suit
def test_mhclo_template_pieces_do_not_cross(draper):
    """The pieces of a MakeHuman suit refit crossing each other; its template is untangled."""
    from physdrape.garments import load_mhclo
    from physdrape.geometry.intersections import self_intersecting_faces

    crossed = SUIT.parents[1] / "female_casualsuit01" / "female_casualsuit01.mhclo"
    raw = load_mhclo(crossed)
    assert len(self_intersecting_faces(raw.verts, raw.faces)) > 0  # else this test proves nothing
    t = draper.garment(str(crossed))
    assert len(self_intersecting_faces(t.verts, t.faces)) == 0


@needs_suit
def test_a_start_whose_pieces_cross_is_skinned_again_without_the_compression_bound(draper, monkeypatch):
    """X_init's compression bound carries a jacket's side through the trousers where a pose bends
    them (male_casualsuit02, a raised arm): that job's start is skinned without the bound, the
    other jobs keep theirs, and the layer order is built on the start the job takes."""
    from physdrape.geometry.intersections import piece_crossings
    from physdrape.pipeline import POSE_DTYPE, DrapePipeline, PosedBodies

    path = SUIT.parents[1] / "male_casualsuit02" / "male_casualsuit02.mhclo"
    suit, tee = draper.garment(str(path)), draper.garment("default")
    piece = garment_parts(suit.verts, suit.faces).piece
    body, material = draper.body("anny"), draper.material(None)

    def state(pose: str) -> PosedBodies:
        return PosedBodies(body(draper.shape({"weight": 0.5}).to(POSE_DTYPE),
                                draper.poses(pose)[0].pose.to(POSE_DTYPE)))

    bent, relaxed = state("random:2"), state("relaxed")
    jobs = [Job(tee, 0, material, layers=True), Job(suit, 0, material, layers=True)]
    pipeline, unbounded = DrapePipeline(body), DrapePipeline(body, x_init_limits={"min_stretch": None})
    got = pipeline.build(jobs, bent)
    rows = slice(int(got.garments.vert_offsets[1]), None)
    assert piece_crossings(got.x_init[rows].numpy(), suit.faces, piece) == 0
    # the suit takes the start skinned without the bound, its layer order built on it
    want = unbounded.build(jobs, bent)
    assert torch.equal(got.x_init[rows], want.x_init[rows])
    assert torch.equal(got.cloth.layers.normal, want.cloth.layers.normal)
    # the tee keeps its bounded start
    assert torch.equal(got.x_init[:rows.start], pipeline.build(jobs[:1], bent).x_init)
    # where the pieces do not cross, the bound stays: the start a pipeline that never skins again gives
    kept = pipeline.build(jobs, relaxed).x_init
    monkeypatch.setattr(DrapePipeline, "_unbounded_candidates", lambda self, jobs: [])
    plain = DrapePipeline(body)
    crossed = plain.build(jobs, bent).x_init[rows].numpy()
    assert piece_crossings(crossed, suit.faces, piece) > 0  # else this test proves nothing
    assert torch.equal(kept, plain.build(jobs, relaxed).x_init)
