"""Body-surface queries on every available device: BVHs built, refitted and searched where the
body vertices live, with the CPU's answers."""

from __future__ import annotations

import pytest
import torch
import trimesh
from closest_point_reference import closest_point_on_triangle
from device_params import DEVICES

from physdrape.geometry.proximity import BodySurface, SignMethod


def _spheres(dtype=torch.float64) -> tuple[torch.Tensor, torch.Tensor]:
    m = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    verts = torch.tensor(m.vertices, dtype=dtype)
    return torch.stack([0.15 * verts, 0.2 * verts + torch.tensor([0.0, 0.1, 0.0], dtype=dtype)]), \
        torch.tensor(m.faces, dtype=torch.int64)


def _unambiguous(points: torch.Tensor, verts: torch.Tensor, faces: torch.Tensor, gap: float = 1e-6) -> torch.Tensor:
    """Per point (B, N), whether its closest point on the body is unique by a clear margin: every
    other point of the surface at least `gap` farther (float64 brute force over all faces). The
    BVHs search in float32, so where two faces' closest points lie within float32 rounding of the
    same distance, either is a right answer and the CPU's and the GPU's may differ (by up to
    sqrt(2 d δ), tens of micrometres at d = 0.1 m)."""
    out = []
    tri = verts[:, faces]  # (B, F, 3, 3)
    for b in range(points.shape[0]):
        a, bb, c = (tri[b, :, k][None] for k in range(3))
        closest, _ = closest_point_on_triangle(points[b][:, None], a, bb, c)  # (N, F, 3)
        dist = (points[b][:, None] - closest).norm(dim=-1)
        best = dist.argmin(dim=1)
        nearest = closest[torch.arange(len(best)), best]
        other = (closest - nearest[:, None]).norm(dim=-1) > 1e-7  # faces whose closest point differs
        second = torch.where(other, dist, torch.full_like(dist, float("inf"))).min(dim=1).values
        out.append(second - dist.min(dim=1).values > gap)
    return torch.stack(out)


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
        # Both answers are closest points: at the same distance (to float32 rounding), on the body.
        dist = (points - got.closest.cpu()).norm(dim=-1)
        torch.testing.assert_close(dist, (points - want.closest).norm(dim=-1), atol=1e-6, rtol=0)
        corners = verts[torch.arange(2)[:, None, None], faces[got.face.cpu()]]  # (B, N, 3, 3)
        torch.testing.assert_close((got.bary.cpu()[..., None] * corners).sum(-2), got.closest.cpu(), atol=1e-7, rtol=0)
        # Where the closest point is unique by a clear margin, the same answer; a float32 winding
        # number may also differ within a micrometre of the surface.
        same = _unambiguous(points, verts, faces)
        assert same.float().mean() > 0.9  # the comparison below covers most points
        clear = same & (want.signed_distance.abs() > 1e-6)
        torch.testing.assert_close(got.closest.cpu()[same], want.closest[same], atol=1e-9, rtol=0)
        for name in ("normal", "signed_distance", "inside"):
            torch.testing.assert_close(getattr(got, name).cpu()[clear], getattr(want, name)[clear], atol=1e-9, rtol=0)
        verts = verts * 1.1  # the bodies move: refit on both
        cpu.update(verts)
        surface.update(verts.to(device))
    packed = points.reshape(-1, 3).to(device).requires_grad_(True)
    body = torch.arange(2, device=device).repeat_interleave(3000)
    surface.query(packed, body_index=body).signed_distance.sum().backward()
    assert packed.grad.device.type == device and bool(torch.isfinite(packed.grad).all())


@pytest.mark.parametrize("device", DEVICES)
def test_walks_on_device_match_the_cpus(device):
    """query(near=...) walks from the given faces on the surface's device, to the CPU's faces, on
    a batch of two bodies with packed points."""
    verts, faces = _spheres()
    g = torch.Generator().manual_seed(1)
    points = torch.randn(2, 2000, 3, dtype=torch.float64, generator=g) * 0.12
    cpu = BodySurface(verts, faces)
    surface = cpu.to(device)
    start = cpu.query(points).face
    moved = points + 2e-3 * torch.randn(points.shape, dtype=points.dtype, generator=g)
    body = torch.arange(2).repeat_interleave(2000)
    want = cpu.query(moved.reshape(-1, 3), body_index=body, near=start.reshape(-1))
    got = surface.query(moved.reshape(-1, 3).to(device), body_index=body.to(device), near=start.reshape(-1).to(device))
    assert got.face.device.type == device and not torch.equal(want.face, start.reshape(-1))
    assert torch.equal(got.face.cpu(), want.face)  # float64 tests in a fixed order: the same walk
    torch.testing.assert_close(got.closest.cpu(), want.closest, atol=1e-12, rtol=0)
    # each body's walk stays on that body: its closest points are the BVH's on the same body
    searched = cpu.query(moved.reshape(-1, 3), body_index=body)
    torch.testing.assert_close((moved.reshape(-1, 3) - want.closest).norm(dim=-1),
                               (moved.reshape(-1, 3) - searched.closest).norm(dim=-1), atol=1e-6, rtol=0)
