"""`Draper(device=...)`: drapes on every available device agree with the CPU's, and a device this
machine cannot run on is refused with an error that names the fix."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from device_params import DEVICES

from physdrape.api import DrapeError, Draper


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")
def test_cuda_without_a_gpu_is_refused_with_the_fix(tiny_checkpoint):
    with pytest.raises(DrapeError, match="device='cpu'") as info:
        Draper(tiny_checkpoint, device="cuda")
    assert "CPU-only build" in str(info.value) or "sees no GPU" in str(info.value)


def test_unsupported_device_is_refused(tiny_checkpoint):
    with pytest.raises(DrapeError, match="runs on 'cpu' or 'cuda'"):
        Draper(tiny_checkpoint, device="mps")


@pytest.mark.anny
@pytest.mark.parametrize("device", DEVICES)
def test_drape_on_device_matches_the_cpu(device, draper, anny_body, tiny_checkpoint):
    on_device = draper if device == "cpu" else Draper(tiny_checkpoint, steps=3, body=anny_body, device=device)
    assert on_device.device.type == device
    assert {p.device.type for p in on_device.model.state_dict().values()} == {device}
    results = on_device.drape(["default", "default"], material=["silk", "denim"], pose=["stand", "t-pose"],
                              keep_trace=True)
    expected = draper.drape(["default", "default"], material=["silk", "denim"], pose=["stand", "t-pose"],
                            keep_trace=True)
    for got, want in zip(results, expected):
        assert isinstance(got.verts, np.ndarray) and got.verts.dtype == np.float32
        assert np.isfinite(got.verts).all() and all(np.isfinite(v) for v in got.metrics.values())
        np.testing.assert_allclose(got.verts, want.verts, atol=1e-4)
        np.testing.assert_allclose(got.body_verts, want.body_verts, atol=1e-6)
        assert len(got.convergence["energy"]) == 4
        assert got.metrics["strain"] == pytest.approx(want.metrics["strain"], rel=1e-2, abs=1e-7)
    [refined] = on_device.drape("default", refine=True, refine_iters=1)  # the oracle runs on the CPU
    assert np.isfinite(refined.verts).all()
