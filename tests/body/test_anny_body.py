"""The Anny backend: frame, rest pose, skinning transforms, normals, topology, bad input."""

from __future__ import annotations

from collections import Counter

import pytest
import torch

from physdrape.body.anny_body import NUM_HM08_VERTS, PHENOTYPE_NAMES
from physdrape.body.anny_data import ANNY_TO_YUP
from physdrape.body.model import apply_transforms

pytestmark = pytest.mark.anny


def random_shape(n, seed, dtype=torch.float64):
    return torch.rand(n, 6, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def random_pose(body, n, seed, scale=0.3, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    return scale * torch.randn(n, body.num_joints, 3, generator=g, dtype=dtype)


def test_canonical_body_is_y_up_facing_plus_z(anny_body):
    v = anny_body.canonical_verts(dtype=torch.float64)
    assert v.shape == (anny_body.num_verts, 3)
    height = v[:, 1].max() - v[:, 1].min()
    assert 1.6 < height < 1.9
    # head above the feet, left side at +x, toes in front (+z) of the heels
    j = anny_body.rest_joints(anny_body.default_shape(1, dtype=torch.float64))[0]
    ix = anny_body.joint_index
    assert j[ix("head"), 1] > j[ix("foot.L"), 1] + 1.2
    assert j[ix("upperarm01.L"), 0] > 0.1 and j[ix("upperarm01.R"), 0] < -0.1
    assert j[ix("toe1-1.L"), 2] > j[ix("foot.L"), 2] + 0.05
    # the upper arms hang ~48 deg below the horizontal (Anny's rest A-pose)
    d = j[ix("lowerarm01.L")] - j[ix("upperarm01.L")]
    assert 35 < float(torch.rad2deg(torch.atan2(-d[1], d[0]))) < 60


def test_frame_rotation_is_proper():
    assert torch.allclose(ANNY_TO_YUP @ ANNY_TO_YUP.T, torch.eye(3, dtype=torch.float64))
    assert torch.det(ANNY_TO_YUP) == pytest.approx(1.0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_rest_pose_reproduces_canonical(anny_body, dtype):
    st = anny_body(anny_body.default_shape(2, dtype=dtype), anny_body.rest_pose(2, dtype=dtype))
    assert st.verts.dtype == dtype and st.normals.dtype == dtype
    canon = anny_body.canonical_verts(dtype=dtype)
    tol = 1e-6 if dtype == torch.float32 else 1e-12
    assert (st.verts - canon).abs().max() < tol
    assert (st.rest_verts - canon).abs().max() < tol
    eye = torch.eye(4, dtype=dtype)
    assert (st.vertex_transforms - eye).abs().max() < tol
    canon += 1.0  # each call hands out its own copy of the canonical body it formed once
    assert (anny_body.canonical_verts(dtype=dtype) - st.rest_verts[0]).abs().max() < tol


@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-12)])
def test_vertex_transforms_reproduce_verts(anny_body, dtype, tol):
    shape, pose = random_shape(3, 0, dtype), random_pose(anny_body, 3, 1, dtype=dtype)
    transl = torch.tensor([[0.1, -0.2, 0.3]], dtype=dtype).expand(3, 3)
    st = anny_body(shape, pose, transl=transl)
    B, V = 3, anny_body.num_verts
    assert st.verts.shape == (B, V, 3) and st.rest_verts.shape == (B, V, 3)
    assert st.vertex_transforms.shape == (B, V, 4, 4) and st.normals.shape == (B, V, 3)
    assert st.faces.dtype == torch.int64 and st.faces.shape == (anny_body.num_faces, 3)
    assert st.joints.shape == (B, anny_body.num_joints, 3)
    assert (apply_transforms(st.vertex_transforms, st.rest_verts) - st.verts).abs().max() < tol
    assert torch.equal(st.vertex_transforms[..., 3, :], torch.tensor([0, 0, 0, 1], dtype=dtype).expand(B, V, 4))
    # the rotation parts of the blended transforms are near-rigid only where one bone dominates;
    # the pose really moved the body
    assert (st.verts - st.rest_verts).abs().max() > 0.05


def test_matches_anny_own_forward(anny_body):
    """Independent check: Anny's own skinning, fed our posed bone frames ('world' poses),
    gives our vertices (rotated back to Anny's z-up frame)."""
    import anny

    m = anny.Anny()
    dt = torch.float64
    shape, pose = random_shape(2, 3), random_pose(anny_body, 2, 4, scale=0.4)
    st = anny_body(shape, pose)
    coeffs = m._get_phenotype_blendshape_coefficients(shape, shape.new_zeros(2, 0), shape.new_zeros(2, 0))
    R_rest = m.get_rest_model(coeffs)["rest_bone_poses"][..., :3, :3]
    C = ANNY_TO_YUP.to(dt)
    W = torch.eye(4, dtype=dt).repeat(2, anny_body.num_joints, 1, 1)
    W[..., :3, :3] = C.T @ st.joint_rotations @ C @ R_rest
    W[..., :3, 3] = st.joints @ C
    out = m(pose_parameters=W, phenotype_kwargs=shape, pose_parameterization="world")
    theirs = out["vertices"][:, anny_body._data.vertex_ids] @ C.T
    assert (theirs - st.verts).abs().max() < 1e-6
    assert (out["rest_vertices"][:, anny_body._data.vertex_ids] @ C.T - st.rest_verts).abs().max() < 1e-9


def test_normals_outward_and_unit(anny_body):
    for pose in (anny_body.rest_pose(1, dtype=torch.float64), random_pose(anny_body, 1, 5, scale=0.2)):
        st = anny_body(anny_body.default_shape(1, dtype=torch.float64), pose)
        n, v = st.normals[0], st.verts[0]
        assert (n.norm(dim=-1) - 1).abs().max() < 1e-9
        assert ((n * (v - v.mean(0))).sum(-1)).mean() > 0.01
        tri = v[st.faces]
        volume = (tri[:, 0] * torch.linalg.cross(tri[:, 1], tri[:, 2])).sum() / 6
        assert 0.04 < volume < 0.12  # [m^3], positive = outward winding


def test_surface_is_closed_manifold(anny_body):
    f = anny_body.faces
    edges = torch.cat([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]).sort(1).values
    counts = Counter(map(tuple, edges.tolist()))
    assert sum(1 for c in counts.values() if c == 1) == 0  # no boundary edge
    assert sum(1 for c in counts.values() if c > 2) == 0  # no non-manifold edge
    assert int(f.max()) + 1 == anny_body.num_verts
    assert anny_body.skinning_weights.shape == (anny_body.num_verts, anny_body.num_joints)
    assert (anny_body.skinning_weights.sum(1) - 1).abs().max() < 1e-6


def test_hm08_vertices(anny_body):
    for shape in (anny_body.default_shape(1, dtype=torch.float64), random_shape(1, 7)):
        h = anny_body.hm08_verts(shape)
        assert h.shape == (1, NUM_HM08_VERTS, 3)
        rest = anny_body.rest_verts(shape)
        # same skin positions in both topologies (Anny's nudity edits do not move these)
        assert (h[:, anny_body.hm08_ids] - rest).norm(dim=-1).max() < 1e-9
    assert int(anny_body.hm08_ids.max()) < 13380  # the skin is hm08's first 13,380 vertices


def test_broadcast_and_dtype(anny_body):
    st = anny_body(anny_body.default_shape(1), random_pose(anny_body, 4, 6, dtype=torch.float32))
    assert st.verts.shape[0] == 4 and st.verts.dtype == torch.float32
    st2 = anny_body(random_shape(4, 8, torch.float32), anny_body.rest_pose(1))
    assert st2.verts.shape[0] == 4
    mats = torch.eye(3).repeat(2, anny_body.num_joints, 1, 1)
    st3 = anny_body(anny_body.default_shape(2), mats)
    assert (st3.verts - anny_body.canonical_verts()).abs().max() < 1e-6


def test_shape_changes_body(anny_body):
    light = anny_body.shape_from_dict({"weight": 0.0}, dtype=torch.float64)
    heavy = anny_body.shape_from_dict({"weight": 1.0}, dtype=torch.float64)
    def volume(shape):
        v = anny_body.rest_verts(shape)[0][anny_body.faces]
        return float((v[:, 0] * torch.linalg.cross(v[:, 1], v[:, 2])).sum() / 6)
    assert volume(heavy) > 1.15 * volume(light)


def test_bad_input_errors(anny_body):
    s, p = anny_body.default_shape(1), anny_body.rest_pose(1)
    with pytest.raises(ValueError, match=r"shape must have shape \(B, 6\)"):
        anny_body(s[:, :5], p)
    with pytest.raises(ValueError, match="outside \\[0, 1\\]"):
        anny_body(s + 0.6, p)
    with pytest.raises(ValueError, match="'weight'"):
        anny_body(torch.tensor([[0.5, 0.5, 0.5, -0.1, 0.5, 0.5]]), p)
    with pytest.raises(ValueError, match="NaN"):
        anny_body(s, p.clone().fill_(float("nan")))
    with pytest.raises(ValueError, match="NaN"):
        anny_body(torch.full_like(s, float("nan")), p)
    with pytest.raises(ValueError, match=r"\(B, 104, 3\)"):
        anny_body(s, p[:, :50])
    with pytest.raises(TypeError, match="floating-point"):
        anny_body(s, p.long())
    with pytest.raises(TypeError, match="one dtype"):
        anny_body(s, p.double())
    with pytest.raises(ValueError, match="batch"):
        anny_body(anny_body.default_shape(2), anny_body.rest_pose(3))
    with pytest.raises(ValueError, match="unknown phenotypes"):
        anny_body.shape_from_dict({"bmi": 0.3})
    with pytest.raises(KeyError, match="unknown joint"):
        anny_body.joint_index("LeftArm")
    assert anny_body.phenotype_names == PHENOTYPE_NAMES


def test_gradients_match_finite_differences(anny_body):
    """d verts / d (pose, shape) in float64 against central differences (a few entries)."""
    base_pose = random_pose(anny_body, 1, 9, scale=0.3)
    base_shape = random_shape(1, 10) * 0.6 + 0.2
    joints = [anny_body.joint_index(n) for n in ("upperarm01.L", "lowerleg01.R", "spine03")]
    vids = torch.tensor([5000, 12000])

    def f(pose_entries, shape):
        pose = base_pose.clone()
        pose[0, joints] = pose_entries
        return anny_body(shape, pose).verts[0, vids]

    x = base_pose[0, joints].clone().requires_grad_()
    s = base_shape.clone().requires_grad_()
    assert torch.autograd.gradcheck(f, (x, s), eps=1e-6, atol=1e-6)
    (g,) = torch.autograd.grad(f(x, s).sum(), x)
    assert g.abs().max() > 1e-3  # not at a stationary point
