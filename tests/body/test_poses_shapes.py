"""Pose presets, the anatomical pose sampler, the arm-through-torso check, the shape sampler."""

from __future__ import annotations

import pytest
import torch
from device_params import DEVICES

from physdrape.body.anny_body import PHENOTYPE_NAMES
from physdrape.body.poses import PRESETS, _set, arm_torso_penetration, preset_pose, sample_poses
from physdrape.body.shapes import sample_shapes


@pytest.mark.anny
def test_presets_are_penetration_free(anny_body):
    s = anny_body.default_shape(1, dtype=torch.float64)
    poses = torch.cat([preset_pose(anny_body, n, dtype=torch.float64) for n in PRESETS])
    # the canonical body and extreme adults (gender, age, muscle, weight, height, proportions)
    extremes = torch.tensor([[0.5] * 6, [0, 1, 0, 1, 0.4, 0], [1, 1, 1, 1, 0.4, 1]],
                            dtype=torch.float64)
    for shape in extremes:
        st = anny_body(shape[None].expand(len(PRESETS), -1), poses)
        assert arm_torso_penetration(st, anny_body).tolist() == [0] * len(PRESETS), shape.tolist()
    # t-pose: the upper arms are horizontal
    tpose = anny_body(s, preset_pose(anny_body, "t-pose", dtype=torch.float64))
    ix = anny_body.joint_index
    for side in "LR":
        d = tpose.joints[0, ix(f"lowerarm01.{side}")] - tpose.joints[0, ix(f"upperarm01.{side}")]
        assert abs(float(d[1])) < 1e-6 * float(d.norm()) + 1e-9
    with pytest.raises(ValueError, match="unknown pose preset"):
        preset_pose(anny_body, "dab")


@pytest.mark.anny
@pytest.mark.parametrize("device", DEVICES)
def test_arm_through_torso_is_detected(anny_body, device):
    s = anny_body.default_shape(1, dtype=torch.float64)
    pose = anny_body.rest_pose(2, dtype=torch.float64)
    _set(pose[:1], anny_body, "upperarm01.L", ez=-45)  # both arms swung into the torso
    counts = arm_torso_penetration(anny_body(s, pose), anny_body, device=device)
    assert counts.device.type == "cpu" and counts[0] > 10 and counts[1] == 0
    if device != "cpu":  # the same count where the search runs
        assert torch.equal(counts, arm_torso_penetration(anny_body(s, pose), anny_body))
    with pytest.raises(ValueError, match="vertices"):
        from physdrape.body.model import BodyState

        v = torch.zeros(1, 10, 3)
        arm_torso_penetration(BodyState(v, torch.zeros(1, 3, dtype=torch.long), v, v, torch.zeros(1, 10, 4, 4)), anny_body)


@pytest.mark.anny
def test_arm_check_refits_its_torso_surface_and_counts_as_a_new_one(anny_body):
    """The check keeps its torso surface per batch size and refits it to each pose: the counts
    of a run of poses, penetrating and not, are those of a surface built for each pose."""
    s = anny_body.default_shape(1, dtype=torch.float64)
    poses = [anny_body.rest_pose(2, dtype=torch.float64) for _ in range(3)]
    _set(poses[0][:1], anny_body, "upperarm01.L", ez=-45)
    _set(poses[2][1:], anny_body, "upperarm01.L", ez=-50)
    poses[1] = sample_poses(anny_body, 2, seed=1, dtype=torch.float64)
    refitted = [arm_torso_penetration(anny_body(s, p), anny_body).tolist() for p in poses]
    assert (2, "cpu") in anny_body.__dict__["_torso_surfaces"]
    fresh = []
    for p in poses:
        anny_body.__dict__.pop("_torso_surfaces")
        fresh.append(arm_torso_penetration(anny_body(s, p), anny_body).tolist())
    assert refitted == fresh
    assert refitted[0][0] > 10 and refitted[2][1] > 10 and refitted[1] == [0, 0]


@pytest.mark.anny
def test_pose_sampler_reproducible_and_penetration_free(anny_body):
    a = sample_poses(anny_body, 4, seed=3)
    b = sample_poses(anny_body, 4, seed=3)
    c = sample_poses(anny_body, 2, seed=4)
    assert a.shape == (4, anny_body.num_joints, 3) and a.dtype == torch.float32
    assert torch.equal(a, b) and not torch.equal(a[:2], c)
    assert (a[:, anny_body.joint_index("root")] == 0).all()
    assert a.abs().max() < 1.2  # [rad], within the joint limits
    for shape in (anny_body.default_shape(1), anny_body.shape_from_dict({"weight": 1.0, "muscle": 1.0})):
        st = anny_body(shape.expand(4, -1), a)
        assert arm_torso_penetration(st, anny_body).tolist() == [0] * 4
    # per-sample shapes: checked on each sample's own body
    shapes = sample_shapes(2, seed=5, dtype=torch.float64)
    p = sample_poses(anny_body, 2, seed=6, shape=shapes, dtype=torch.float64)
    assert arm_torso_penetration(anny_body(shapes, p), anny_body).tolist() == [0] * 2


def test_shape_sampler():
    a = sample_shapes(400, seed=0)
    assert a.shape == (400, len(PHENOTYPE_NAMES)) and a.dtype == torch.float32
    assert torch.equal(a, sample_shapes(400, seed=0)) and not torch.equal(a, sample_shapes(400, seed=1))
    assert a.min() >= 0 and a.max() <= 1
    age = a[:, PHENOTYPE_NAMES.index("age")]
    assert age.min() >= 0.6  # adults only
    for name in ("weight", "muscle"):
        x = a[:, PHENOTYPE_NAMES.index(name)]
        assert (x == 0).sum() > 10 and (x == 1).sum() > 10  # extremes reachable
    with pytest.raises(ValueError, match="age_range"):
        sample_shapes(2, seed=0, age_range=(0.8, 0.2))


@pytest.mark.anny
def test_pose_sampler_rejects_arm_through_torso(anny_body, monkeypatch):
    """With limits that swing the arms into the torso, no returned pose may penetrate."""
    import physdrape.body.poses as poses
    from physdrape.body.poses import PoseSamplerConfig

    limits = dict(poses.JOINT_LIMITS_DEG)
    limits["upperarm01.L"] = ((0, 0), (0, 0), (-60, -40))
    monkeypatch.setattr(poses, "JOINT_LIMITS_DEG", limits)
    raw = poses._draw(anny_body, 2, torch.Generator().manual_seed(0), 1.0)
    s = anny_body.default_shape(1, dtype=torch.float64)
    assert (arm_torso_penetration(anny_body(s, raw), anny_body) > 0).all()  # the draws do penetrate
    out = sample_poses(anny_body, 2, seed=0, config=PoseSamplerConfig(max_tries=1), dtype=torch.float64)
    assert arm_torso_penetration(anny_body(s, out), anny_body).tolist() == [0, 0]


@pytest.mark.anny
@pytest.mark.parametrize("device", DEVICES)
def test_bodies_pose_on_every_device(anny_body, device):
    """The Anny body poses where its inputs are (the Draper poses on its device): the same bodies
    as on the CPU, in float64."""
    shapes = sample_shapes(2, seed=1, dtype=torch.float64)
    poses = sample_poses(anny_body, 2, seed=2, shape=shapes, dtype=torch.float64)
    on_cpu = anny_body(shapes, poses)
    there = anny_body(shapes.to(device), poses.to(device))
    assert there.verts.device.type == device and there.faces.device.type == device
    for name in ("verts", "normals", "rest_verts", "vertex_transforms", "joints"):
        torch.testing.assert_close(getattr(there, name).cpu(), getattr(on_cpu, name), rtol=0, atol=1e-10)
