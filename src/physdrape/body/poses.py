"""Static poses for the Anny rig: named presets, a seeded anatomical sampler that keeps the
arms off the torso, the arm-through-torso check, and the AMASS `.npz` loader (SMPL backend).

Angles are per-bone Euler angles [deg] in the rest-pose world axes (y up, body facing +z,
left side at +x), composed R = Ry(twist) @ Rx(pitch) @ Rz(roll) and converted to the
axis-angle pose of `physdrape.body.model`. Signs, for the left side (the right side mirrors:
y and z negated): x > 0 leans an upward bone forward and swings a downward bone backward
(knee flexion), x < 0 swings a downward bone forward (hip/shoulder flexion, elbow flexion);
z > 0 raises a left limb sideways (abduction).
"""

from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from physdrape.body.model import BodyState, axis_angle_to_matrix, matrix_to_axis_angle

# (x, y, z) ranges in degrees for the left side / the midline of the default "anny" rig.
JOINT_LIMITS_DEG: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "spine05": ((-5, 6), (-5, 5), (-3, 3)),
    "spine04": ((-5, 6), (-5, 5), (-3, 3)),
    "spine03": ((-4, 5), (-5, 5), (-3, 3)),
    "spine02": ((-4, 5), (-5, 5), (-3, 3)),
    "spine01": ((-4, 5), (-5, 5), (-3, 3)),
    "neck01": ((-8, 10), (-10, 10), (-5, 5)),
    "neck02": ((-5, 8), (-8, 8), (-4, 4)),
    "head": ((-10, 10), (-15, 15), (-6, 6)),
    "upperleg01.L": ((-30, 12), (-10, 10), (-4, 12)),
    "lowerleg01.L": ((0, 45), (0, 0), (0, 0)),
    "foot.L": ((-12, 12), (-5, 5), (-4, 4)),
    "clavicle.L": ((-4, 4), (-6, 6), (-2, 8)),
    "upperarm01.L": ((-35, 15), (-20, 20), (0, 40)),
    "lowerarm01.L": ((-60, 0), (0, 0), (0, 0)),
    "wrist.L": ((-15, 15), (-10, 10), (-10, 10)),
}


def _euler_deg_to_rotvec(ex: Tensor, ey: Tensor, ez: Tensor) -> Tensor:
    """R = Ry(ey) @ Rx(ex) @ Rz(ez) from degrees, as axis-angle (..., 3), float64."""
    def rot(axis: int, deg: Tensor) -> Tensor:
        v = torch.zeros(deg.shape + (3,), dtype=torch.float64)
        v[..., axis] = deg.double() * (math.pi / 180.0)
        return axis_angle_to_matrix(v)

    R = rot(1, ey) @ rot(0, ex) @ rot(2, ez)
    return matrix_to_axis_angle(R)


def _mirror(name: str) -> str | None:
    return name[:-2] + ".R" if name.endswith(".L") else None


def _set(pose: Tensor, body, name: str, ex: float = 0.0, ey: float = 0.0, ez: float = 0.0, *, mirror: bool = True) -> None:
    """Write Euler degrees for a joint into pose (1, J, 3); with `mirror`, a ".L" joint's
    mirror ".R" gets the same angles with y and z negated."""
    def write(joint: str, x: float, y: float, z: float) -> None:
        angles = [torch.tensor([float(a)]) for a in (x, y, z)]
        pose[0, body.joint_index(joint)] = _euler_deg_to_rotvec(*angles)[0].to(pose.dtype)

    write(name, ex, ey, ez)
    m = _mirror(name)
    if mirror and m is not None:
        write(m, ex, -ey, -ez)


def _upperarm_elevation_deg(body) -> float:
    """Angle of the canonical left upper arm below the horizontal, [deg]."""
    j = body.rest_joints(body.default_shape(1, dtype=torch.float64))[0]
    d = j[body.joint_index("lowerarm01.L")] - j[body.joint_index("upperarm01.L")]
    return float(torch.rad2deg(torch.atan2(-d[1], d[0].abs())))


PRESETS = ("rest", "a-pose", "t-pose", "relaxed", "stand", "stride", "arms-forward")


def preset_pose(body, name: str, *, dtype: torch.dtype = torch.float32) -> Tensor:
    """A named pose for the Anny "anny" rig, shape (1, J, 3).

    rest / a-pose: Anny's rest A-pose (all zeros); t-pose: upper arms horizontal; relaxed: arms
    slightly lowered, elbows a little bent; stand: natural standing (weight on one leg, head
    turned, elbows bent); stride: a walking step; arms-forward: both arms raised forward.
    """
    if name not in PRESETS:
        raise ValueError(f"unknown pose preset {name!r}; expected one of {PRESETS}")
    if body.rig != "anny":
        raise ValueError(f"pose presets are defined for the 'anny' rig, got {body.rig!r}")
    pose = body.rest_pose(1, dtype=dtype)
    if name in ("rest", "a-pose"):
        return pose
    if name == "t-pose":
        _set(pose, body, "upperarm01.L", ez=_upperarm_elevation_deg(body))
    elif name == "relaxed":
        _set(pose, body, "upperarm01.L", ex=-5, ez=-3)
        _set(pose, body, "lowerarm01.L", ex=-15)
    elif name == "stand":
        _set(pose, body, "upperarm01.L", ex=-8, ez=0)
        _set(pose, body, "lowerarm01.L", ex=-25)
        _set(pose, body, "head", ey=12, ex=4)
        _set(pose, body, "upperleg01.L", ex=-4, ez=6, mirror=False)
        _set(pose, body, "lowerleg01.L", ex=10, mirror=False)
    elif name == "stride":
        _set(pose, body, "upperleg01.L", ex=-22, ez=2, mirror=False)
        _set(pose, body, "upperleg01.R", ex=12, ez=-2, mirror=False)
        _set(pose, body, "lowerleg01.L", ex=15, mirror=False)
        _set(pose, body, "lowerleg01.R", ex=25, mirror=False)
        _set(pose, body, "upperarm01.L", ex=15, mirror=False)
        _set(pose, body, "upperarm01.R", ex=-20, mirror=False)
        _set(pose, body, "lowerarm01.L", ex=-20)
    elif name == "arms-forward":
        _set(pose, body, "upperarm01.L", ex=-60, ez=10)
        _set(pose, body, "lowerarm01.L", ex=-20)
    return pose


# ----------------------------------------------------------------------------------------------
# Arms through the torso


_ARM_BONES = {
    "anny": (("upperarm01",), ("upperarm02", "lowerarm", "wrist", "finger", "metacarpal")),
    "cmu_mb": (("LeftArm", "RightArm"), ("ForeArm", "Hand", "Thumb", "FingerBase", "HandFinger")),
    # SMPL family (`SMPLBody`): "left_shoulder" drives the upper arm, "left_elbow" the forearm
    "smpl": (("left_shoulder", "right_shoulder"), ("elbow", "wrist", "hand")),
}


def checks_arms(rig: str) -> bool:
    """Whether `arm_torso_penetration` knows the arm bones of body rig `rig`."""
    return rig in _ARM_BONES


def arm_bones(body) -> tuple[Tensor, Tensor]:
    """Per joint of `body`'s rig, whether it is a distal arm bone, and whether an arm bone at all
    (J,) bool each."""
    proximal, distal = _ARM_BONES[body.rig]
    names = body.joint_names
    is_distal = torch.tensor([any(k in n for k in distal) for n in names])
    return is_distal, is_distal | torch.tensor([any(n.startswith(k) for k in proximal) for n in names])


def arm_sets(body) -> tuple[Tensor, Tensor]:
    """(query vertex ids on the distal arms, face mask of the non-arm 'torso' surface)."""
    cache = body.__dict__.setdefault("_arm_sets_cache", {})
    if "v" in cache:
        return cache["v"], cache["f"]
    is_distal, is_arm = arm_bones(body)
    part = body.vertex_part()
    query = torch.nonzero(is_distal[part]).squeeze(1)
    torso_faces = ~is_arm[part][body.faces].any(1)
    cache["v"], cache["f"] = query, torso_faces
    return query, torso_faces


def arm_torso_penetration(body_state: BodyState, body=None, *, stride: int = 4,
                          device: torch.device | str | None = None) -> Tensor:
    """Number of distal-arm vertices (upper arm's distal half, forearm, hand) inside the rest of
    the body (torso, head, legs) for each posed body.

    The query vertices and the non-arm surface come from the dominant skinning bone of each
    vertex; inside = generalised winding number > 0.5 w.r.t. the non-arm surface (open only at
    the shoulders, far from the queried vertices), by `geometry.proximity.BodySurface`. Every
    `stride`-th query vertex is tested.

    Args:
        body_state: posed bodies of `body` (B, Vb, 3).
        body: the `AnnyBody` that produced them (default: the shared "anny" rig body).
        device: where the torso's BVH is built and searched (default: where the bodies are; a
            drape on a GPU checks its poses there).
    Returns:
        counts, shape (B,) int64 on the CPU; 0 = no arm vertex inside the body.
    """
    if body is None:
        from physdrape.body.anny_body import get_anny_body

        body = get_anny_body()
    if body_state.verts.shape[1] != body.num_verts:
        raise ValueError(
            f"body_state has {body_state.verts.shape[1]} vertices but the {body.rig!r} Anny body "
            f"has {body.num_verts}; pass the body that produced the state"
        )
    query, torso = arm_sets(body)
    with torch.no_grad():
        verts = body_state.verts.to(device=device, dtype=torch.float32)
        with TORSO_LOCK:
            surface = torso_surface(body, torso, verts)
            inside = surface.inside(verts[:, query[::stride].to(verts.device)])
    return inside.sum(dim=1).cpu()


#: Guards the torso surfaces `torso_surface` keeps (poses checked on parallel threads share them).
TORSO_LOCK = threading.Lock()


def torso_surface(body, torso: Tensor, verts: Tensor):
    """The non-arm surface of `body` at posed vertices (B, Vb, 3) float32: built once per batch
    size and device, then refitted to each new pose (a refit costs a fraction of a BVH build, and
    the check's few hundred points barely feel a tree built for another pose). Call under
    `TORSO_LOCK`."""
    from physdrape.geometry.proximity import BodySurface

    cache = body.__dict__.setdefault("_torso_surfaces", {})
    key = (verts.shape[0], str(verts.device))
    surface = cache.get(key)
    if surface is None:
        # Accuracy 2 (Warp's default): on this open surface 1.0 misses points just above
        # w = 0.5 that the exact (brute-force) winding number counts; 2.0 agrees with it.
        surface = cache[key] = BodySurface(verts.clone(), body.faces[torso].to(verts.device), winding_accuracy=2.0)
    else:
        surface.update(verts.clone())
    return surface


# ----------------------------------------------------------------------------------------------
# The sampler


@dataclass(frozen=True)
class PoseSamplerConfig:
    """Scale of the joint limits (1 = `JOINT_LIMITS_DEG`) and the rejection budget."""

    limit_scale: float = 1.0
    max_tries: int = 20
    stride: int = 4


def _draw(body, num: int, g: torch.Generator, scale: float) -> Tensor:
    pose = torch.zeros(num, body.num_joints, 3, dtype=torch.float64)
    for name, lims in JOINT_LIMITS_DEG.items():
        sides = [(name, 1.0)] + ([(_mirror(name), -1.0)] if _mirror(name) else [])
        for jname, sign in sides:
            u = torch.rand(num, 3, generator=g, dtype=torch.float64)
            ang = [scale * (lo + (hi - lo) * u[:, k]) for k, (lo, hi) in enumerate(lims)]
            pose[:, body.joint_index(jname)] = _euler_deg_to_rotvec(ang[0], sign * ang[1], sign * ang[2])
    return pose


def sample_poses(
    body,
    num: int,
    *,
    seed: int,
    shape: Tensor | None = None,
    config: PoseSamplerConfig = PoseSamplerConfig(),
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Draw `num` anatomically plausible static poses for the Anny "anny" rig, reproducibly.

    Each joint of `JOINT_LIMITS_DEG` gets uniform Euler angles within its limits (fingers, toes
    and the root stay at rest); the shoulders are only abducted from the rest A-pose (arms kept
    off the torso). A pose whose arm vertices end up inside the body (`arm_torso_penetration`,
    checked on `shape`, default the canonical body) is redrawn; after `config.max_tries` failed
    draws its angles are halved until it is clear (a RuntimeError if even that fails).

    Returns:
        poses, shape (num, J, 3) axis-angle.
    """
    if body.rig != "anny":
        raise ValueError(f"the pose sampler is defined for the 'anny' rig, got {body.rig!r}")
    g = torch.Generator().manual_seed(int(seed))
    out = _draw(body, num, g, config.limit_scale)
    if shape is None:
        shape = body.default_shape(1, dtype=torch.float64)
    shape = shape.to(torch.float64)
    todo = torch.arange(num)
    for _ in range(config.max_tries):
        if len(todo) == 0:
            break
        st = body(shape.expand(len(todo), -1) if shape.shape[0] == 1 else shape[todo], out[todo])
        bad = arm_torso_penetration(st, body, stride=config.stride) > 0
        todo = todo[bad]
        if len(todo):
            out[todo] = _draw(body, len(todo), g, config.limit_scale)
    for _ in range(8):
        if len(todo) == 0:
            break
        out[todo] = out[todo] * 0.5
        st = body(shape.expand(len(todo), -1) if shape.shape[0] == 1 else shape[todo], out[todo])
        todo = todo[arm_torso_penetration(st, body, stride=config.stride) > 0]
    if len(todo):
        raise RuntimeError(
            f"could not find arm-clear poses for samples {todo.tolist()}: even near the rest pose "
            "the arms of this body shape are inside the torso; use a less extreme shape"
        )
    return out.to(dtype)


# ----------------------------------------------------------------------------------------------
# AMASS


def load_amass_npz(
    path: str | os.PathLike,
    *,
    num_joints: int = 24,
    num_betas: int = 10,
    z_up: bool = True,
    dtype: torch.dtype = torch.float32,
) -> dict[str, Tensor | str | float]:
    """Read an AMASS sequence (`poses` (N, 156) SMPL+H axis-angles, `betas`, `trans`).

    Only `poses` is required: a missing `trans` reads as zeros, missing `betas` as β = 0.

    Args:
        num_joints: joints of the target model: 24 (SMPL; AMASS's 22 body joints plus the two
            hand joints left at zero), 52 (SMPL+H), 55 (SMPL-X) or 22. When the file has exactly
            `num_joints` joints all are copied; otherwise only the 22 body joints (the hand /
            face joints of SMPL, SMPL+H and SMPL-X differ) and the rest stay at zero.
        z_up: AMASS is z-up; rotate the root orientation and translation by -90° about x into
            the y-up frame (the pelvis offset from the origin is neglected, a few cm of shift).
    Returns:
        dict with pose (N, num_joints, 3), betas (num_betas,), transl (N, 3), gender (str) and
        fps (float).
    """
    if not os.path.isfile(path):
        raise FileNotFoundError(f"AMASS file not found: {path}")
    with np.load(path, allow_pickle=False) as z:
        if "poses" not in z.files:
            raise ValueError(f"{path} is not an AMASS sequence: missing 'poses' (has {z.files}); an AMASS "
                             "frame file holds poses (N, 3J) axis-angles [rad], optionally betas and trans")
        poses = torch.as_tensor(z["poses"], dtype=torch.float64)
        trans = (torch.as_tensor(z["trans"], dtype=torch.float64) if "trans" in z.files
                 else torch.zeros(max(poses.shape[0], 0) if poses.dim() else 0, 3, dtype=torch.float64))
        betas = torch.as_tensor(z["betas"], dtype=torch.float64) if "betas" in z.files else torch.zeros(num_betas)
        gender = str(z["gender"]) if "gender" in z.files else "neutral"
        fps = float(z["mocap_framerate"]) if "mocap_framerate" in z.files else float("nan")
    if poses.dim() != 2 or poses.shape[1] % 3:
        raise ValueError(f"{path}: poses must have shape (N, 3J), got {tuple(poses.shape)}")
    aa = poses.reshape(poses.shape[0], -1, 3)
    n_src = aa.shape[1]
    pose = torch.zeros(aa.shape[0], num_joints, 3, dtype=torch.float64)
    k = n_src if n_src == num_joints else min(22, num_joints, n_src)
    pose[:, :k] = aa[:, :k]
    if z_up:
        Rx = axis_angle_to_matrix(torch.tensor([-math.pi / 2, 0.0, 0.0], dtype=torch.float64))
        pose[:, 0] = matrix_to_axis_angle(Rx @ axis_angle_to_matrix(pose[:, 0]))
        trans = trans @ Rx.T
    b = torch.zeros(num_betas, dtype=torch.float64)
    nb = min(num_betas, betas.numel())
    b[:nb] = betas.reshape(-1)[:nb]
    return {"pose": pose.to(dtype), "betas": b.to(dtype), "transl": trans.to(dtype), "gender": gender, "fps": fps}
