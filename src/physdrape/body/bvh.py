"""BVH motion capture: a parser, forward kinematics, and the retarget onto Anny's ``cmu_mb`` rig.

The CMU files in ``data/cmu_bvh`` use 3ds-Max-style joint names (LeftHip, LeftKnee, Chest2, ...);
Anny's ``cmu_mb`` rig is the same 31-joint CMU skeleton with MotionBuilder-style names (LeftUpLeg,
LeftLeg, Spine1, ...). `CMU_MAX_TO_MB` is the explicit map; files that already use the
MotionBuilder names are accepted as they are.

BVH semantics used here: a joint's rotation channels are intrinsic Euler angles [deg] applied in
the listed order (``Zrotation Yrotation Xrotation`` -> R = Rz @ Ry @ Rx) about axes that, in the
rest pose, are the world axes; world rotation G_c = G_parent @ R_c, joint position
p_c = p_parent + G_parent @ offset_c. That is exactly the pose convention of
`physdrape.body.model`, so a BVH frame is a pose of its own skeleton.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import torch
from torch import Tensor

from physdrape.body.model import axis_angle_to_matrix, euler_to_matrix, forward_kinematics, matrix_to_axis_angle

CMU_MAX_TO_MB: dict[str, str] = {
    "Hips": "Hips",
    "LHipJoint": "LHipJoint",
    "LeftHip": "LeftUpLeg",
    "LeftKnee": "LeftLeg",
    "LeftAnkle": "LeftFoot",
    "LeftToe": "LeftToeBase",
    "RHipJoint": "RHipJoint",
    "RightHip": "RightUpLeg",
    "RightKnee": "RightLeg",
    "RightAnkle": "RightFoot",
    "RightToe": "RightToeBase",
    "lowerback": "LowerBack",
    "Chest": "Spine",
    "Chest2": "Spine1",
    "lowerneck": "Neck",
    "Neck": "Neck1",
    "Head": "Head",
    "LeftCollar": "LeftShoulder",
    "LeftShoulder": "LeftArm",
    "LeftElbow": "LeftForeArm",
    "LeftWrist": "LeftHand",
    "lhand": "LeftFingerBase",
    "LFingers": "LeftHandFinger1",
    "LThumb": "LThumb",
    "RightCollar": "RightShoulder",
    "RightShoulder": "RightArm",
    "RightElbow": "RightForeArm",
    "RightWrist": "RightHand",
    "rhand": "RightFingerBase",
    "RFingers": "RightHandFinger1",
    "RThumb": "RThumb",
}
"""3ds-Max-style CMU joint name -> Anny ``cmu_mb`` (MotionBuilder-style) bone name."""

_AXES = {"Xrotation": "X", "Yrotation": "Y", "Zrotation": "Z"}
_POS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


@dataclass(frozen=True)
class BVHMotion:
    """A parsed BVH file (units of the file, y-up as CMU/BVH).

    Attributes:
        joint_names: (J,) in file order (parents before children).
        parents: (J,) parent index, -1 for the root.
        offsets: rest offset of each joint from its parent [file units], shape (J, 3).
        end_sites: joint index -> End Site offset, shape (3,).
        channels: per joint, its channel names in file order.
        frame_time: [s].
        motion: raw channel values, shape (N, C).
    """

    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: Tensor
    end_sites: dict[int, Tensor]
    channels: tuple[tuple[str, ...], ...]
    frame_time: float
    motion: Tensor

    @property
    def num_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    def _columns(self):
        col = 0
        for ch in self.channels:
            yield col, ch
            col += len(ch)

    def local_rotations(self) -> Tensor:
        """Per-frame local rotation of each joint, shape (N, J, 3, 3)."""
        N = self.num_frames
        out = torch.eye(3, dtype=self.motion.dtype).repeat(N, self.num_joints, 1, 1)
        for j, (col, ch) in enumerate(self._columns()):
            rot = [(k, _AXES[c]) for k, c in enumerate(ch) if c in _AXES]
            if rot:
                angles = torch.deg2rad(self.motion[:, [col + k for k, _ in rot]])
                out[:, j] = euler_to_matrix(angles, "".join(a for _, a in rot))
        return out

    def local_translations(self) -> Tensor:
        """Offset plus position channels of each joint [file units], shape (N, J, 3)."""
        out = self.offsets.expand(self.num_frames, -1, -1).clone()
        for j, (col, ch) in enumerate(self._columns()):
            for k, c in enumerate(ch):
                if c in _POS:
                    out[:, j, _POS[c]] += self.motion[:, col + k]
        return out

    def rest_positions(self) -> Tensor:
        """Rest-pose joint positions (root at its offset) [file units], shape (J, 3)."""
        pos = torch.zeros(self.num_joints, 3, dtype=self.offsets.dtype)
        for j, p in enumerate(self.parents):
            pos[j] = self.offsets[j] + (pos[p] if p >= 0 else 0)
        return pos

    def forward_kinematics(self) -> tuple[Tensor, Tensor]:
        """World joint positions [file units] (N, J, 3) and world rotations (N, J, 3, 3)."""
        R = self.local_rotations()
        rest = self.rest_positions()
        # Joint translations other than the root's are their rest offsets (CMU has no others).
        G, joints, _ = forward_kinematics(R, rest.expand(self.num_frames, -1, -1), self.parents)
        root = self.local_translations()[:, 0]
        return joints + (root - rest[0])[:, None], G


def load_bvh(path: str | os.PathLike, *, dtype: torch.dtype = torch.float64) -> BVHMotion:
    """Parse a BVH file (HIERARCHY + MOTION)."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"BVH file not found: {path}")
    with open(path) as fh:
        text = fh.read()
    head, sep, motion = text.partition("MOTION")
    if not sep:
        raise ValueError(f"{path}: not a BVH file (no MOTION section)")
    tok = head.split()
    if not tok or tok[0] != "HIERARCHY":
        raise ValueError(f"{path}: not a BVH file (must start with HIERARCHY)")
    names, parents, offsets, channels, ends = [], [], [], [], {}
    stack: list[int] = []
    i, pending = 1, None
    while i < len(tok):
        t = tok[i]
        if t in ("ROOT", "JOINT"):
            names.append(tok[i + 1])
            parents.append(stack[-1] if stack else -1)
            offsets.append([0.0, 0.0, 0.0])
            channels.append(())
            pending = len(names) - 1
            i += 2
        elif t == "End":
            pending = "end"
            i += 2
        elif t == "{":
            stack.append(pending if pending != "end" else -2)
            i += 1
        elif t == "}":
            stack.pop()
            i += 1
        elif t == "OFFSET":
            vals = [float(x) for x in tok[i + 1 : i + 4]]
            if stack[-1] == -2:
                ends[stack[-2]] = torch.tensor(vals, dtype=dtype)
            else:
                offsets[stack[-1]] = vals
            i += 4
        elif t == "CHANNELS":
            n = int(tok[i + 1])
            channels[stack[-1]] = tuple(tok[i + 2 : i + 2 + n])
            i += 2 + n
        else:
            raise ValueError(f"{path}: unexpected token {t!r} in HIERARCHY")
    lines = motion.strip().splitlines()
    nframes = int(lines[0].split(":")[1])
    frame_time = float(lines[1].split(":")[1])
    rows = [[float(x) for x in ln.split()] for ln in lines[2 : 2 + nframes] if ln.strip()]
    ncols = sum(len(c) for c in channels)
    if len(rows) != nframes or any(len(r) != ncols for r in rows):
        raise ValueError(f"{path}: expected {nframes} frames of {ncols} values")
    return BVHMotion(
        joint_names=tuple(names),
        parents=tuple(parents),
        offsets=torch.tensor(offsets, dtype=dtype),
        end_sites=ends,
        channels=tuple(channels),
        frame_time=frame_time,
        motion=torch.tensor(rows, dtype=dtype).reshape(nframes, ncols),
    )


def map_joint_names(names: tuple[str, ...], expected: tuple[str, ...]) -> dict[str, str]:
    """BVH joint -> rig bone, through `CMU_MAX_TO_MB` or identity; raises on unknown joints."""
    mapping, unknown = {}, []
    for n in names:
        m = CMU_MAX_TO_MB.get(n, n)
        if m in expected:
            mapping[n] = m
        else:
            unknown.append(n)
    if unknown:
        raise ValueError(
            f"unknown BVH joints {unknown}: expected the CMU skeleton with 3ds-Max names "
            f"{sorted(CMU_MAX_TO_MB)} or Anny cmu_mb names {sorted(expected)}"
        )
    missing = sorted(set(expected) - set(mapping.values()))
    if missing:
        raise ValueError(f"BVH file lacks joints for the cmu_mb bones {missing}")
    return mapping


def _min_rotation(a: Tensor, b: Tensor) -> Tensor:
    """Smallest rotation taking direction a to direction b, (..., 3) -> (..., 3, 3)."""
    a = a / a.norm(dim=-1, keepdim=True)
    b = b / b.norm(dim=-1, keepdim=True)
    axis = torch.linalg.cross(a, b)
    s, c = axis.norm(dim=-1, keepdim=True), (a * b).sum(-1, keepdim=True)
    angle = torch.atan2(s, c)
    unit = torch.where(s > 1e-12, axis / s.clamp_min(1e-12), torch.zeros_like(axis))
    # antiparallel: any axis orthogonal to a
    anti = (s <= 1e-12) & (c < 0)
    if bool(anti.any()):
        ortho = torch.linalg.cross(a, torch.tensor([1.0, 0.0, 0.0], dtype=a.dtype).expand_as(a))
        ortho = torch.where(ortho.norm(dim=-1, keepdim=True) < 1e-6,
                            torch.linalg.cross(a, torch.tensor([0.0, 1.0, 0.0], dtype=a.dtype).expand_as(a)), ortho)
        unit = torch.where(anti, ortho / ortho.norm(dim=-1, keepdim=True), unit)
    return axis_angle_to_matrix(unit * angle)


@dataclass(frozen=True)
class Retarget:
    """Result of `retarget_bvh`: pose (N, 31, 3) and transl (N, 3) [m] for the cmu_mb rig, and
    the BVH joint driving each bone (`source`, one per cmu_mb bone)."""

    pose: Tensor
    transl: Tensor
    source: tuple[str, ...]
    alignment: Tensor  # (31, 3, 3): rest alignment A_c (Anny rest bone -> BVH rest bone)


def retarget_bvh(motion: BVHMotion, body, *, shape: Tensor | None = None, frames=None) -> Retarget:
    """Retarget a CMU BVH onto an Anny ``cmu_mb`` body.

    Each bone c takes the world rotation of its BVH joint b composed with a fixed rest
    alignment, G_c = G_b @ A_c, where A_c is the smallest rotation turning the Anny rest bone
    (head to the head of its child) onto the BVH rest bone (joint to the mapped child; End Site
    for leaves; a bone of zero length in either skeleton inherits its parent's A). Posed bone
    directions then equal the BVH ones exactly, whatever the bone lengths. The root translation
    is the BVH root motion relative to the first frame, scaled by the ratio of leg lengths.

    Args:
        motion: a parsed BVH (`load_bvh`).
        body: ``AnnyBody(rig="cmu_mb")``.
        shape: phenotypes (1, 6) the rest alignment is computed on (default: canonical).
        frames: optional index / slice of frames.
    """
    if body.rig != "cmu_mb":
        raise ValueError(f"retarget_bvh needs AnnyBody(rig='cmu_mb'), got rig {body.rig!r}")
    mapping = map_joint_names(motion.joint_names, body.joint_names)
    dtype = torch.float64
    if shape is None:
        shape = body.default_shape(1, dtype=dtype)
    heads = body.rest_joints(shape.to(dtype))[0]
    tails = body.rest_tails(shape.to(dtype))[0]
    bvh_rest = motion.rest_positions().to(dtype)
    src = [motion.joint_names.index(next(k for k, v in mapping.items() if v == bone)) for bone in body.joint_names]
    J = body.num_joints
    children = [[k for k in range(J) if body.parents[k] == c] for c in range(J)]
    A = torch.eye(3, dtype=dtype).repeat(J, 1, 1)
    for c in range(J):
        b = src[c]
        if children[c]:
            k = min(children[c], key=lambda k: float((heads[k] - tails[c]).norm()))
            d_anny = heads[k] - heads[c]
            d_bvh = bvh_rest[src[k]] - bvh_rest[b]
        else:
            d_anny = tails[c] - heads[c]
            d_bvh = motion.end_sites.get(b, torch.zeros(3, dtype=dtype)).to(dtype)
        p = body.parents[c]
        if d_anny.norm() < 1e-9 or d_bvh.norm() < 1e-9:
            A[c] = A[p] if p >= 0 else torch.eye(3, dtype=dtype)
        else:
            A[c] = _min_rotation(d_anny, d_bvh)
    m = motion if frames is None else BVHMotion(
        motion.joint_names, motion.parents, motion.offsets, motion.end_sites, motion.channels,
        motion.frame_time, motion.motion[frames].reshape(-1, motion.motion.shape[1]),
    )
    pos, G_bvh = m.forward_kinematics()
    G = G_bvh[:, src] @ A  # (N, J, 3, 3)
    parents = torch.tensor([max(p, 0) for p in body.parents])
    D = G[:, parents].transpose(-1, -2) @ G
    D[:, 0] = G[:, 0]
    # scale: leg length (hip joint to ankle) Anny / BVH
    iu, ia = body.joint_index("LeftUpLeg"), body.joint_index("LeftFoot")
    bu, ba = src[iu], src[ia]
    scale = float((heads[ia] - heads[iu]).norm() / (bvh_rest[ba] - bvh_rest[bu]).norm())
    root = pos[:, src[0]]
    transl = scale * (root - root[:1])
    return Retarget(
        pose=matrix_to_axis_angle(D),
        transl=transl,
        source=tuple(motion.joint_names[b] for b in src),
        alignment=A,
    )
