"""The body-model interface every backend (Anny, SMPL/SMPL-X) implements, and the kinematics
the backends share.

World frame y-up, metres. A backend maps a batch of (shape, pose) to a `BodyState`: the posed
surface plus what a garment needs to follow the body by linear blend skinning (LBS).

Pose convention shared by every backend (the SMPL one): a pose is one rotation per joint,
``pose`` (B, J, 3) axis-angle [rad] or (B, J, 3, 3) rotation matrices. Joint ``c``'s rotation
``D_c`` is expressed in the axes of the *rest-pose world frame* carried along by its parent:
the world rotation of joint c is ``G_c = G_parent(c) @ D_c`` (``G_root = D_root``) and the
joint turns about its own rest head. All-zero axis-angles reproduce the rest pose exactly.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from physdrape.geometry.normals import vertex_face_table, vertex_normals  # noqa: F401  (re-exported)


@dataclass(frozen=True)
class BodyState:
    """A batch of posed, shaped bodies.

    Attributes:
        verts: posed vertex positions [m], shape (B, Vb, 3).
        faces: triangle indices into verts, shape (Fb, 3) int64 (shared by the batch).
        normals: unit outward vertex normals of the posed surface, shape (B, Vb, 3).
        rest_verts: the same shaped bodies in the model's rest pose [m], shape (B, Vb, 3).
        vertex_transforms: per-vertex LBS transforms taking rest_verts to verts,
            verts = T[..., :3, :3] @ rest + T[..., :3, 3], shape (B, Vb, 4, 4).
        joints: posed joint (bone head) positions [m], shape (B, J, 3); None if the backend
            does not expose joints.
        joint_rotations: world rotation of each joint relative to the rest pose (G_c above),
            shape (B, J, 3, 3); None if not exposed.
    """

    verts: Tensor
    faces: Tensor
    normals: Tensor
    rest_verts: Tensor
    vertex_transforms: Tensor
    joints: Tensor | None = None
    joint_rotations: Tensor | None = None

    @property
    def batch_size(self) -> int:
        return int(self.verts.shape[0])

    @property
    def num_verts(self) -> int:
        return int(self.verts.shape[1])


class BodyModel(ABC):
    """A parametric body: shape and pose parameters in, posed surface out (y-up, metres)."""

    @property
    @abstractmethod
    def faces(self) -> Tensor:
        """Triangles of the body surface, shape (Fb, 3) int64."""

    @abstractmethod
    def canonical_verts(self) -> Tensor:
        """The canonical body garments are authored on: default shape, rest pose [m], (Vb, 3)."""

    @abstractmethod
    def default_shape(self, batch_size: int = 1) -> Tensor:
        """Shape parameters of the canonical body, shape (B, S)."""

    @abstractmethod
    def rest_pose(self, batch_size: int = 1) -> Tensor:
        """Pose parameters of the rest pose, shape (B, *pose_shape)."""

    @abstractmethod
    def __call__(self, shape: Tensor, pose: Tensor) -> BodyState:
        """Pose and shape a batch of bodies: shape (B, S), pose (B, *pose_shape)."""


# ----------------------------------------------------------------------------------------------
# Rotations


def axis_angle_to_matrix(rotvec: Tensor) -> Tensor:
    """Rodrigues' formula, finite with finite gradients at zero.

    Args:
        rotvec: axis * angle [rad], shape (..., 3).
    Returns:
        rotation matrices, shape (..., 3, 3), same dtype.
    """
    theta2 = (rotvec * rotvec).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    small = theta2 < 1e-12
    theta2_safe = torch.where(small, torch.ones_like(theta2), theta2)
    theta = theta2_safe.sqrt()
    # sin(t)/t and (1 - cos t)/t^2 with their Taylor series near zero.
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2_safe)
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    K = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(rotvec.shape + (3,))
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand(K.shape)
    return eye + a * K + b * (K @ K)


def matrix_to_axis_angle(R: Tensor) -> Tensor:
    """Inverse of `axis_angle_to_matrix` (angle in [0, pi]), shape (..., 3, 3) -> (..., 3).

    Through the unit quaternion (w, x, y, z), each found from the largest of 4w², 4x², 4y², 4z²
    (the traces of R's symmetric combinations; Shepperd's method, accurate at every angle,
    π included), w ≥ 0; the angle is 2 atan2(|(x, y, z)|, w), its series near zero."""
    r = [column.unbind(-1) for column in R.unbind(-1)]  # r[j][i] = R[..., i, j]
    m00, m10, m20 = r[0]
    m01, m11, m21 = r[1]
    m02, m12, m22 = r[2]
    squares = torch.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    largest = squares.argmax(-1, keepdim=True)
    sq = squares.clamp_min(0.0)
    w_x_y_z = [  # the quaternion from each of the four, times 4 × that component (normalised below)
        torch.stack([sq[..., 0], m21 - m12, m02 - m20, m10 - m01], -1),
        torch.stack([m21 - m12, sq[..., 1], m01 + m10, m02 + m20], -1),
        torch.stack([m02 - m20, m01 + m10, sq[..., 2], m12 + m21], -1),
        torch.stack([m10 - m01, m02 + m20, m12 + m21, sq[..., 3]], -1),
    ]
    q = torch.gather(torch.stack(w_x_y_z, -2), -2, largest[..., None].expand(*largest.shape, 4)).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    q = torch.where(q[..., :1] < 0, -q, q)
    w, v = q[..., 0], q[..., 1:]
    n = v.norm(dim=-1)
    small = n < 1e-8
    n_safe = torch.where(small, torch.ones_like(n), n)
    scale = torch.where(small, 2.0 / w, 2.0 * torch.atan2(n, w) / n_safe)  # angle / |v|, 2/w + O(|v|²)
    return v * scale[..., None]


def euler_to_matrix(angles: Tensor, order: str) -> Tensor:
    """Intrinsic Euler rotations as BVH applies them: R = R_order[0] @ R_order[1] @ R_order[2].

    Args:
        angles: [rad], shape (..., 3), angles[..., i] about axis order[i].
        order: a permutation of "XYZ", e.g. "ZYX" or "ZXY".
    Returns:
        shape (..., 3, 3).
    """
    axes = {"X": 0, "Y": 1, "Z": 2}
    R = None
    for i, ax in enumerate(order.upper()):
        v = torch.zeros(angles.shape[:-1] + (3,), dtype=angles.dtype, device=angles.device)
        v[..., axes[ax]] = angles[..., i]
        Ri = axis_angle_to_matrix(v)
        R = Ri if R is None else R @ Ri
    return R


def pose_to_matrices(pose: Tensor, num_joints: int, *, name: str = "pose") -> Tensor:
    """Check a pose batch and return rotation matrices (B, J, 3, 3).

    Accepts (B, J, 3) axis-angle, (B, J*3) flat axis-angle (SMPL's θ) or (B, J, 3, 3).
    """
    if not isinstance(pose, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(pose).__name__}")
    if pose.dim() == 2 and pose.shape[1] == 3 * num_joints:
        pose = pose.reshape(pose.shape[0], num_joints, 3)
    if pose.dim() == 3 and pose.shape[1:] == (num_joints, 3):
        mats = None
    elif pose.dim() == 4 and pose.shape[1:] == (num_joints, 3, 3):
        mats = pose
    else:
        raise ValueError(
            f"{name} must have shape (B, {num_joints}, 3) axis-angle, (B, {3 * num_joints}) "
            f"or (B, {num_joints}, 3, 3) rotation matrices; got {tuple(pose.shape)}"
        )
    if not pose.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {pose.dtype}")
    if not bool(torch.isfinite(pose).all()):
        bad = (~torch.isfinite(pose)).reshape(pose.shape[0], num_joints, -1).any(-1)
        b, j = bad.nonzero()[0].tolist()
        raise ValueError(
            f"{name} contains NaN/inf values (first at batch {b}, joint {j}); "
            "expected finite rotations"
        )
    return axis_angle_to_matrix(pose) if mats is None else mats


# ----------------------------------------------------------------------------------------------
# Kinematics and skinning


def joint_levels(parents: Sequence[int]) -> list[tuple[Tensor, Tensor]]:
    """Joints grouped by depth for `forward_kinematics`: [(joint ids, parent ids), ...]."""
    parents = [int(p) for p in parents]
    depth = [0] * len(parents)
    for j, p in enumerate(parents):
        if p >= j and p >= 0:
            raise ValueError(f"parents must be topologically sorted (joint {j} has parent {p})")
        depth[j] = 0 if p < 0 else depth[p] + 1
    levels = []
    for d in range(1, max(depth, default=0) + 1):
        ids = [j for j in range(len(parents)) if depth[j] == d]
        levels.append((torch.tensor(ids), torch.tensor([parents[j] for j in ids])))
    return levels


def forward_kinematics(
    rotations: Tensor,
    rest_joints: Tensor,
    parents: Sequence[int],
    *,
    levels: list[tuple[Tensor, Tensor]] | None = None,
) -> tuple[Tensor, Tensor, Tensor]:
    """Posed joints of a kinematic tree in the convention of this module.

    Args:
        rotations: local rotations D_c, shape (B, J, 3, 3).
        rest_joints: rest positions of the joints (bone heads) [m], shape (B, J, 3).
        parents: parent index of each joint, -1 for the (single) root at index 0, sorted so
            that a parent comes before its children.
        levels: precomputed `joint_levels(parents)` (optional, saves a little time).
    Returns:
        G: world rotations relative to the rest pose, shape (B, J, 3, 3);
        joints: posed joint positions [m], shape (B, J, 3) (the root stays at its rest head);
        transforms: rigid bone transforms taking rest to posed, shape (B, J, 3, 4):
            x_posed = T[..., :3] @ x_rest + T[..., 3].
    """
    if levels is None:
        levels = joint_levels(parents)
    B, J = rotations.shape[:2]
    rest_joints = rest_joints.expand(B, J, 3)
    G = rotations[:, :1]
    q = rest_joints[:, :1]
    order = [torch.zeros(1, dtype=torch.long)]
    # Per level, gather the parents' results from the concatenation of the previous levels.
    position = torch.empty(J, dtype=torch.long)
    position[0] = 0
    count = 1
    Gs, qs = [G], [q]
    G_all, q_all = G, q
    for ids, par in levels:
        pp = position[par]
        Gp = G_all[:, pp]
        Gc = Gp @ rotations[:, ids]
        offs = (rest_joints[:, ids] - rest_joints[:, par]).unsqueeze(-1)
        qc = q_all[:, pp] + (Gp @ offs).squeeze(-1)
        position[ids] = torch.arange(count, count + len(ids))
        count += len(ids)
        Gs.append(Gc)
        qs.append(qc)
        order.append(ids)
        G_all = torch.cat(Gs, 1)
        q_all = torch.cat(qs, 1)
    inverse = torch.argsort(torch.cat(order))
    G = G_all[:, inverse]
    joints = q_all[:, inverse]
    t = joints - (G @ rest_joints.unsqueeze(-1)).squeeze(-1)
    return G, joints, torch.cat([G, t.unsqueeze(-1)], -1)


def blend_transforms(weights: Tensor, bone_transforms: Tensor) -> Tensor:
    """Per-vertex LBS transforms Σ_j w_vj T_j.

    Args:
        weights: dense skinning weights, shape (V, J), rows summing to 1.
        bone_transforms: shape (B, J, 3, 4).
    Returns:
        shape (B, V, 3, 4).
    """
    B, J = bone_transforms.shape[:2]
    flat = bone_transforms.permute(1, 0, 2, 3).reshape(J, B * 12)
    out = (weights @ flat).reshape(-1, B, 3, 4)
    return out.permute(1, 0, 2, 3)


def apply_transforms(T: Tensor, x: Tensor) -> Tensor:
    """x' = T[..., :3] @ x + T[..., 3] for T (..., 3|4, 4) and x (..., 3)."""
    return (T[..., :3, :3] @ x.unsqueeze(-1)).squeeze(-1) + T[..., :3, 3]


def to_homogeneous(T: Tensor) -> Tensor:
    """(..., 3, 4) -> (..., 4, 4) with the bottom row [0, 0, 0, 1]."""
    bottom = torch.zeros(T.shape[:-2] + (1, 4), dtype=T.dtype, device=T.device)
    bottom[..., 0, 3] = 1.0
    return torch.cat([T, bottom], -2)


def check_batch(x: Tensor, name: str, trailing: tuple[int, ...], *, batch_size: int | None = None) -> None:
    """Raise a ValueError naming `name` unless x has shape (B, *trailing) and is finite float."""
    if not isinstance(x, Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.dim() != 1 + len(trailing) or tuple(x.shape[1:]) != trailing:
        want = ", ".join(["B"] + [str(t) for t in trailing])
        raise ValueError(f"{name} must have shape ({want}); got {tuple(x.shape)}")
    if batch_size is not None and x.shape[0] != batch_size:
        raise ValueError(f"{name} has batch size {x.shape[0]}, expected {batch_size}")
    if not x.is_floating_point():
        raise TypeError(f"{name} must be a floating-point tensor, got {x.dtype}")
    if not bool(torch.isfinite(x).all()):
        raise ValueError(f"{name} contains NaN/inf values; expected finite numbers")


def broadcast_batch(shape: Tensor, pose: Tensor) -> tuple[Tensor, Tensor]:
    """Broadcast a batch of 1 against a batch of B (error if both > 1 and different)."""
    bs, bp = shape.shape[0], pose.shape[0]
    if bs == bp:
        return shape, pose
    if bs == 1:
        return shape.expand(bp, *shape.shape[1:]), pose
    if bp == 1:
        return shape, pose.expand(bs, *pose.shape[1:])
    raise ValueError(f"shape batch ({bs}) and pose batch ({bp}) differ; expected equal or one of them 1")
