"""Warm-started BVH sequences on a tiny test model: frame A is the cold drape, later frames start
from the previous drape carried along by the body (and so differ from the cold ones)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from physdrape.api import Motion

BVH_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "cmu_bvh"
BVH_FILES = sorted(BVH_DIR.glob("*.bvh")) if BVH_DIR.is_dir() else []
ANNY_CACHE = Path.home() / ".cache" / "anny"

needs_data = pytest.mark.skipif(not BVH_FILES, reason=f"no CMU BVH files in {BVH_DIR}")
needs_anny = pytest.mark.skipif(not (ANNY_CACHE.is_dir() and any(ANNY_CACHE.rglob("*"))),
                                reason=f"the Anny body is not cached in {ANNY_CACHE} (a first build takes ~1 min)")


@pytest.mark.anny
@needs_data
@needs_anny
def test_warm_start_bvh(tiny_checkpoint, anny_cmu_body):
    from physdrape.api import Draper

    draper = Draper(tiny_checkpoint, steps=3, body=anny_cmu_body)
    motion = Motion(BVH_FILES[0], frames=(0, 3))
    assert motion.warm_start  # the default for sequences
    warm = draper.drape("default", pose=motion)
    cold = draper.drape("default", pose=Motion(BVH_FILES[0], frames=(0, 3), warm_start=False))
    assert [r.init for r in warm] == ["skinning", "warm", "warm"] and {r.init for r in cold} == {"skinning"}
    assert [r.pose for r in warm] == [r.pose for r in cold] == [f"{BVH_FILES[0].name}#{k}" for k in range(3)]
    np.testing.assert_allclose(warm[0].verts, cold[0].verts, atol=2e-5)
    for w, c in zip(warm[1:], cold[1:]):
        assert np.isfinite(w.verts).all() and np.isfinite(w.x_init).all()
        assert np.abs(w.verts - c.verts).max() > 1e-4
        assert np.abs(w.x_init - c.x_init).max() > 1e-4  # frame t starts from frame t-1's drape
        np.testing.assert_allclose(w.body_verts, c.body_verts, atol=1e-6)
        assert all(np.isfinite(v) for v in w.metrics.values())
    # a single frame has nothing to chain: cold
    [single] = draper.drape("default", pose=Motion(BVH_FILES[0], frames=1))
    np.testing.assert_allclose(single.verts, cold[1].verts, atol=2e-5)
    assert single.init == "skinning"


@pytest.mark.anny
@needs_data
@needs_anny
def test_warm_modes(tiny_checkpoint, anny_cmu_body):
    """The tiny model's network outputs zero, so the physics-only continuation ("solver", the
    default) must equal the full model pass ("model") exactly: the two share solver and handler."""
    from physdrape.api import DrapeError, Draper

    draper = Draper(tiny_checkpoint, steps=2, body=anny_cmu_body)
    solver = draper.drape("default", pose=Motion(BVH_FILES[0], frames=(5, 7)))
    model = draper.drape("default", pose=Motion(BVH_FILES[0], frames=(5, 7), warm_start="model"))
    assert [r.init for r in model] == ["skinning", "warm"]
    for a, b in zip(solver, model):
        np.testing.assert_allclose(a.verts, b.verts, atol=1e-6)
    with pytest.raises(DrapeError, match="warm_start must be"):
        Motion(BVH_FILES[0], frames=(0, 2), warm_start="yes")


@pytest.mark.anny
@needs_data
@needs_anny
def test_a_motions_arms_are_turned_out_where_they_hang_against_the_torso(tiny_checkpoint, anny_cmu_body):
    """Frame 100 of 131_01 hangs its arms against the torso: by default they are turned out at the
    shoulders (and the result says by how much); with clear_arms=False the frame is draped as
    recorded, and a drape that ends partly inside the body says so with a DrapeWarning."""
    import warnings

    from physdrape.api import Draper, DrapeWarning

    path = BVH_DIR / "131_01.bvh"
    if not path.is_file():
        pytest.skip(f"no {path}")
    draper = Draper(tiny_checkpoint, steps=2, body=anny_cmu_body)
    [turned] = draper.drape("default", pose=Motion(path, frames=100))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DrapeWarning)
        [kept] = draper.drape("default", pose=Motion(path, frames=100, clear_arms=False))
    assert kept.arms_turned_out_deg is None and "arms_turned_out_deg" not in kept.report()
    assert len(turned.arms_turned_out_deg) == 2 and max(turned.arms_turned_out_deg) > 0
    assert turned.report()["arms_turned_out_deg"] == list(turned.arms_turned_out_deg)
    assert np.abs(turned.body_verts - kept.body_verts).max() > 0.01  # the turned body is the one draped on
    inside = [w for w in caught if issubclass(w.category, DrapeWarning) and "inside the body" in str(w.message)]
    assert bool(inside) == (kept.metrics["b2g_percent"] > 0)


def test_a_motions_clear_arms_must_be_a_bool():
    from physdrape.api import DrapeError

    with pytest.raises(DrapeError, match="clear_arms must be True"):
        Motion("walk.bvh", frames=1, clear_arms="no")
