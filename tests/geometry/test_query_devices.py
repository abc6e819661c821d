"""Body-surface queries on every available device: BVHs built, refitted and searched where the
body vertices live, with the CPU's answers."""

from __future__ import annotations

import pytest
import torch
import trimesh
from device_params import DEVICES

from physdrape.geometry.proximity import BodySurface, SignMethod


def _spheres(dtype=torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    verts = torch.tensor(m.vertices, dtype=dtype)
    return torch.stack([0.15 * verts, 0.2 * verts + torch.tensor([0.0, 0.1, 0.0], dtype=dtype)]), \
        torch.tensor(m.faces, dtype=torch.int64)


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("sign", list(SignMethod))
def test_queries_on_device_match_the_cpu(device, sign):
    verts, faces = _spheres()
    points = torch.randn(2, 3000, 3, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 0.12
    cpu = BodySurface(verts, faces, sign_method=sign)
    surface = cpu.to(device)
    assert surface.device.type == device and surface.faces.device.type == device
    assert cpu.to("cpu") is cpu
    for step in range(2):
        got, want = surface.query(points.to(device)), cpu.query(points)
        assert all(getattr(got, f).device.type == device for f in ("closest", "normal", "signed_distance", "inside"))
        if device == "cpu":  # the same BVHs: the same answers, bit for bit
            for name in ("closest", "normal", "signed_distance", "bary", "face", "inside"):
                assert torch.equal(getattr(got, name), getattr(want, name)), name
            continue
        # the GPU's BVHs may break ties between faces sharing the closest edge or vertex otherwise,
        # and its float32 winding number may differ within a micrometre of the surface
        clear = want.signed_distance.abs() > 1e-6
        torch.testing.assert_close(got.closest.cpu(), want.closest, atol=1e-9, rtol=0)
        for name in ("normal", "signed_distance", "inside"):
            torch.testing.assert_close(getattr(got, name).cpu()[clear], getattr(want, name)[clear], atol=1e-9, rtol=0)
        moved = verts * 1.1  # the bodies move: refit on both
        cpu.update(moved)
        surface.update(moved.to(device))
    packed = points.reshape(-1, 3).to(device).requires_grad_(True)
    body = torch.arange(2, device=device).repeat_interleave(3000)
    surface.query(packed, body_index=body).signed_distance.sum().backward()
    assert packed.grad.device.type == device and bool(torch.isfinite(packed.grad).all())
