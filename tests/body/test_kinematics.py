"""Shared kinematics of physdrape.body.model against slow / independent twins (no Anny needed)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from physdrape.body.model import (
    axis_angle_to_matrix,
    blend_transforms,
    euler_to_matrix,
    forward_kinematics,
    matrix_to_axis_angle,
    pose_to_matrices,
    vertex_face_table,
    vertex_normals,
)

SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]


def test_axis_angle_matches_scipy_and_is_smooth_at_zero():
    g = torch.Generator().manual_seed(0)
    rv = torch.randn(50, 3, generator=g, dtype=torch.float64) * 2
    ours = axis_angle_to_matrix(rv)
    ref = torch.from_numpy(Rotation.from_rotvec(rv.numpy()).as_matrix())
    assert (ours - ref).abs().max() < 1e-12
    x = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    R = axis_angle_to_matrix(x)
    (grad,) = torch.autograd.grad(R[0, 1] + R[2, 0], x)
    assert torch.isfinite(grad).all() and grad.abs().max() > 0.5  # d/dθ of the skew part


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_matrix_to_axis_angle_matches_scipy_at_every_angle(dtype, tol):
    """Random rotations, tiny angles and angles at and next to π: scipy's rotation vector (at π,
    where v and −v are one rotation, the same rotation)."""
    g = torch.Generator().manual_seed(1)
    axis = torch.nn.functional.normalize(torch.randn(60, 3, generator=g, dtype=torch.float64), dim=-1)
    angle = torch.cat([torch.rand(30, generator=g, dtype=torch.float64) * math.pi,
                       torch.tensor([0.0, 1e-12, 1e-8, 1e-5, 1e-2]).double(),
                       math.pi - torch.tensor([1e-1, 1e-3, 1e-6]).double(), torch.full((22,), math.pi).double()])
    R = axis_angle_to_matrix(axis * angle[:, None])
    ours = matrix_to_axis_angle(R.to(dtype)).double()
    ref = torch.from_numpy(Rotation.from_matrix(R.numpy()).as_rotvec())
    away = angle < math.pi - 1e-4
    assert (ours - ref)[away].abs().max() < tol
    assert (axis_angle_to_matrix(ours) - R).abs().max() < 10 * tol  # at π too
    assert ours.norm(dim=-1).max() <= math.pi + tol


@pytest.mark.parametrize("order", ["ZYX", "ZXY", "XYZ"])
def test_euler_matches_scipy_intrinsic(order):
    a = torch.tensor([[0.3, -1.1, 0.7], [2.0, 0.1, -0.4]], dtype=torch.float64)
    ref = Rotation.from_euler(order, a.numpy()).as_matrix()
    assert np.abs(euler_to_matrix(a, order).numpy() - ref).max() < 1e-12


def slow_fk(R, rest, parents):
    """Per-joint loop twin of forward_kinematics."""
    B, J = R.shape[:2]
    G = [None] * J
    q = [None] * J
    for j, p in enumerate(parents):
        if p < 0:
            G[j], q[j] = R[:, j], rest[:, j]
        else:
            G[j] = G[p] @ R[:, j]
            q[j] = q[p] + (G[p] @ (rest[:, j] - rest[:, p])[..., None])[..., 0]
    return torch.stack(G, 1), torch.stack(q, 1)


def test_forward_kinematics_matches_loop_values_and_gradients():
    g = torch.Generator().manual_seed(1)
    rv = (0.5 * torch.randn(3, 24, 3, generator=g, dtype=torch.float64)).requires_grad_()
    rest = torch.randn(3, 24, 3, generator=g, dtype=torch.float64)
    G, q, T = forward_kinematics(axis_angle_to_matrix(rv), rest, SMPL_PARENTS)
    G2, q2 = slow_fk(axis_angle_to_matrix(rv), rest, SMPL_PARENTS)
    assert (G - G2).abs().max() < 1e-12 and (q - q2).abs().max() < 1e-12
    # T maps each rest joint onto its posed position
    assert ((T[..., :3] @ rest[..., None])[..., 0] + T[..., 3] - q).abs().max() < 1e-12
    (ga,) = torch.autograd.grad(q.sum() + G.sum(), rv)
    (gb,) = torch.autograd.grad(q2.sum() + G2.sum(), rv)
    assert (ga - gb).abs().max() < 1e-10 and ga.abs().max() > 1e-3


def test_blend_transforms_and_normals_twins():
    g = torch.Generator().manual_seed(2)
    W = torch.rand(40, 5, generator=g, dtype=torch.float64)
    W = W / W.sum(1, keepdim=True)
    T = torch.randn(2, 5, 3, 4, generator=g, dtype=torch.float64)
    ref = torch.einsum("vj,bjik->bvik", W, T)
    assert (blend_transforms(W, T) - ref).abs().max() < 1e-12
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=2)
    v = torch.tensor(m.vertices, dtype=torch.float64)[None]
    f = torch.tensor(m.faces, dtype=torch.long)
    n1 = vertex_normals(v, f)
    n2 = vertex_normals(v, f, table=vertex_face_table(f, v.shape[1]))
    assert (n1 - n2).abs().max() < 1e-12
    assert ((n1[0] * v[0]).sum(-1) > 0.99).all()  # unit sphere: normal = position


def test_pose_checks():
    with pytest.raises(ValueError, match=r"\(B, 24, 3\)"):
        pose_to_matrices(torch.zeros(1, 23, 3), 24)
    with pytest.raises(ValueError, match="NaN"):
        pose_to_matrices(torch.full((1, 24, 3), math.nan), 24)
    assert pose_to_matrices(torch.zeros(2, 72), 24).shape == (2, 24, 3, 3)
