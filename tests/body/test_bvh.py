"""BVH parsing, forward kinematics against an independent implementation, and the retarget
onto Anny's cmu_mb rig."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from physdrape.body.bvh import CMU_MAX_TO_MB, load_bvh, map_joint_names, retarget_bvh

DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "cmu_bvh"
BVH_FILES = sorted(DATA.glob("*.bvh"))
needs_data = pytest.mark.skipif(not BVH_FILES, reason=f"no CMU BVH files in {DATA}")

TINY = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT Spine
  {
    OFFSET 0 2 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 1 0
    }
  }
  JOINT Leg
  {
    OFFSET 1 -1 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 -3 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.01
0 0 0 0 0 0 0 0 0 0 0 0
1 2 3 90 0 0 0 90 0 45 0 0
"""


def independent_fk(motion):
    """Per-frame, per-joint 4x4 products with scipy's Euler angles (intrinsic = upper case)."""
    N, J = motion.num_frames, motion.num_joints
    out = np.zeros((N, J, 3))
    raw = motion.motion.numpy()
    for n in range(N):
        world = [None] * J
        col = 0
        for j in range(J):
            ch = motion.channels[j]
            vals = raw[n, col : col + len(ch)]
            col += len(ch)
            M = np.eye(4)
            M[:3, 3] = motion.offsets[j].numpy()
            pos = {c: v for c, v in zip(ch, vals) if c.endswith("position")}
            M[:3, 3] += [pos.get("Xposition", 0.0), pos.get("Yposition", 0.0), pos.get("Zposition", 0.0)]
            rot = [(c[0], v) for c, v in zip(ch, vals) if c.endswith("rotation")]
            if rot:
                M[:3, :3] = Rotation.from_euler("".join(a for a, _ in rot), [v for _, v in rot], degrees=True).as_matrix()
            p = motion.parents[j]
            world[j] = M if p < 0 else world[p] @ M
            out[n, j] = world[j][:3, 3]
    return out


def test_tiny_bvh_parse_and_fk(tmp_path):
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY)
    m = load_bvh(path)
    assert m.joint_names == ("Hips", "Spine", "Leg") and m.parents == (-1, 0, 0)
    assert m.num_frames == 2 and m.frame_time == pytest.approx(0.01)
    assert torch.equal(m.end_sites[2], torch.tensor([0.0, -3.0, 0.0], dtype=torch.float64))
    pos, _ = m.forward_kinematics()
    assert np.abs(pos.numpy() - independent_fk(m)).max() < 1e-12
    # frame 1: root at (1,2,3) turned 90 deg about z: the spine offset (0,2,0) points to -x
    assert np.allclose(pos[1, 1].numpy(), [1 - 2, 2, 3])


def test_bvh_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_bvh(tmp_path / "missing.bvh")
    (tmp_path / "bad.bvh").write_text("HELLO")
    with pytest.raises(ValueError, match="not a BVH"):
        load_bvh(tmp_path / "bad.bvh")
    (tmp_path / "short.bvh").write_text(TINY.replace("Frames: 2", "Frames: 3"))
    with pytest.raises(ValueError, match="expected 3 frames"):
        load_bvh(tmp_path / "short.bvh")
    with pytest.raises(ValueError, match=r"unknown BVH joints \['Tail'\].*expected"):
        map_joint_names(tuple(CMU_MAX_TO_MB) + ("Tail",), tuple(CMU_MAX_TO_MB.values()))


@needs_data
@pytest.mark.parametrize("path", BVH_FILES, ids=lambda p: p.name)
def test_cmu_fk_matches_independent_fk(path):
    m = load_bvh(path)
    assert m.num_joints == 31 and set(m.joint_names) == set(CMU_MAX_TO_MB)
    sub = type(m)(m.joint_names, m.parents, m.offsets, m.end_sites, m.channels, m.frame_time, m.motion[::97])
    pos, _ = sub.forward_kinematics()
    assert np.abs(pos.numpy() - independent_fk(sub)).max() < 1e-9


@needs_data
@pytest.mark.anny
def test_retarget_reproduces_bone_directions(anny_cmu_body):
    """What can be compared exactly: the bone lengths differ between the skeletons, so we
    compare the posed direction of every bone (parent joint -> child joint) of the retargeted
    Anny rig with the same bone of the BVH skeleton posed by its own FK."""
    body = anny_cmu_body
    m = load_bvh(BVH_FILES[0])
    frames = slice(0, m.num_frames, 60)
    r = retarget_bvh(m, body, frames=frames)
    shape = body.default_shape(1, dtype=torch.float64)
    st = body(shape, r.pose, transl=r.transl)
    sub = type(m)(m.joint_names, m.parents, m.offsets, m.end_sites, m.channels, m.frame_time, m.motion[frames])
    pos, _ = sub.forward_kinematics()
    src = [m.joint_names.index(n) for n in r.source]
    assert [CMU_MAX_TO_MB[n] for n in r.source] == list(body.joint_names)
    heads, tails = body.rest_joints(shape)[0], body.rest_tails(shape)[0]
    compared = 0
    for c in range(body.num_joints):
        kids = [k for k in range(body.num_joints) if body.parents[k] == c]
        if not kids:
            continue
        k = min(kids, key=lambda k: float((heads[k] - tails[c]).norm()))
        da = st.joints[:, k] - st.joints[:, c]
        db = pos[:, src[k]] - pos[:, src[c]]
        if float(da[0].norm()) < 1e-6 or float(db[0].norm()) < 1e-9:
            continue  # zero-length bone in one skeleton: no direction to compare
        cos = (da / da.norm(dim=-1, keepdim=True) * db / db.norm(dim=-1, keepdim=True)).sum(-1)
        assert (1 - cos).abs().max() < 1e-9, body.joint_names[c]
        compared += 1
    assert compared >= 18
    # plausible: head above the feet in every frame (the dancer bends over in a few)
    ix = body.joint_index
    rise = st.joints[:, ix("Head"), 1] - st.joints[:, ix("LeftFoot"), 1]
    assert (rise > 0.5).all() and rise.median() > 1.2


@pytest.mark.anny
def test_cmu_rig_shares_the_surface(anny_body, anny_cmu_body):
    assert anny_cmu_body.num_joints == 31 and set(anny_cmu_body.joint_names) == set(CMU_MAX_TO_MB.values())
    assert torch.equal(anny_cmu_body.faces, anny_body.faces)
    assert (anny_cmu_body.canonical_verts() - anny_body.canonical_verts()).abs().max() < 1e-6


@pytest.mark.anny
def test_retarget_needs_cmu_rig(anny_body, tmp_path):
    path = tmp_path / "tiny.bvh"
    path.write_text(TINY)
    with pytest.raises(ValueError, match="cmu_mb"):
        retarget_bvh(load_bvh(path), anny_body)
