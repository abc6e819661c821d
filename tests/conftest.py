"""Shared fixtures. The Anny body is loaded once per test session (Anny caches its first build,
~1 min, on disk under ~/.cache/anny; later loads take about a second)."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(scope="session")
def anny_body():
    """The shared default-rig `AnnyBody` (104 bones, 13,348-vertex closed skin)."""
    from physdrape.body.anny_body import get_anny_body

    return get_anny_body("anny")


@pytest.fixture
def winding_searches(monkeypatch):
    """The sizes of the body BVHs' winding-number searches (`BodyBVH.closest_faces(winding=True)`)
    made during the test, in order (clear it where the count should start)."""
    from physdrape.geometry.body_bvh import BodyBVH

    asked, search = [], BodyBVH.closest_faces

    def counting(self, points, body, **kwargs):
        if kwargs.get("winding"):
            asked.append(len(points))
        return search(self, points, body, **kwargs)

    monkeypatch.setattr(BodyBVH, "closest_faces", counting)
    return asked


@pytest.fixture(scope="session")
def anny_cmu_body():
    """The `AnnyBody` on Anny's 31-bone ``cmu_mb`` rig (the BVH retarget target)."""
    from physdrape.body.anny_body import get_anny_body

    return get_anny_body("cmu_mb")


def write_tiny_checkpoint(run_dir) -> str:
    """A 1-block, width-8 PhysDrape whose decoder outputs zero (Δx = 0, f̂ = 0): the drape is X_init
    relaxed by the two-level stretching solver (the shipped model's kind and settings) plus the
    collision handler, so material effects are the physics' own and deterministic."""
    from physdrape.config_io import to_mapping
    from physdrape.model import PhysDrape
    from physdrape.model.config import ModelConfig
    from physdrape.checkpoint import save_checkpoint

    torch.manual_seed(0)
    config = ModelConfig(latent=8, blocks=1, solver="two_level", eta=1.0, gamma=0.98, max_step=0.01, requery_every=3)
    model = PhysDrape(config)
    last = [m for m in model.gnn.decoder.modules() if isinstance(m, torch.nn.Linear)][-1]
    torch.nn.init.zeros_(last.weight)
    torch.nn.init.zeros_(last.bias)
    return str(save_checkpoint(run_dir, 0, model, {"train": {"model": to_mapping(config)}}, keep=1))


@pytest.fixture(autouse=True)
def one_thread():
    """One torch thread for these tests: on a shared 2-core machine it is markedly faster (DESIGN Sec. 5)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture
def threads():
    """Set torch's thread count inside a test (`one_thread` restores it after)."""
    return torch.set_num_threads


@pytest.fixture(scope="session")
def tiny_split(tmp_path_factory) -> str:
    """A garment split of 2 training and 2 test garments (seconds to generate), so that no test
    needs the full 600/30 split a user generates on first training or evaluation."""
    from physdrape.garments.split import make_split

    out = tmp_path_factory.mktemp("tiny_split")
    make_split(out, seed=0, num_train=2, num_test=2)
    return str(out)


@pytest.fixture(scope="session")
def tiny_checkpoint(tmp_path_factory) -> str:
    return write_tiny_checkpoint(tmp_path_factory.mktemp("tiny_model"))
