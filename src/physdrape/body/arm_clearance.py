"""Arms lifted off the torso: the smallest shoulder abduction that leaves a gap for the cloth.

A static drape cannot resolve cloth caught between an arm and the torso: where a hanging arm
touches the torso (motion capture is full of such frames) the posed body's arm and torso surfaces
meet or sink into each other, and the cloth between them has no place outside the body. DrapeNet
and SNUG rotate the shoulders outward on such poses; `clear_arms` does that per arm, by the
smallest angle that puts the arm, from a hand's width below the shoulder to the fingertips, at
least `gap` from the rest of the body.

Each arm is turned about its shoulder joint's head, in the plane of the arm and the line between
the shoulders, away from the torso. The arm's vertices follow that turn rigidly (they are skinned
to the turned bone and those below it), so each candidate angle is measured by turning those
points, without posing the body again; the torso's surface does not move. The angle is the first
of `ANGLES_DEG` whose turned points all clear the gap (where none does, the one that leaves the
arm farthest off), and the pose is changed only where that angle is not 0: an arm already clear
keeps its pose bit for bit.
"""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.body.model import BodyState, axis_angle_to_matrix, matrix_to_axis_angle, pose_to_matrices
from physdrape.geometry.closest_point import closest_point_on_indexed_triangles

#: Gap [m] between an arm and the rest of the body that `clear_arms` makes.
ARM_GAP = 0.02
#: The abductions tried first, in order [deg] (then the whole degrees below the first that clears);
#: the last is the most any arm is turned.
ANGLES_DEG = tuple(float(a) for a in range(0, 46, 3))
#: Every `STRIDE`-th of those arm vertices is measured (as the arm–torso check samples them).
STRIDE = 4
#: Arm vertices nearer their shoulder joint's head [m] are not measured: at the armpit the arm
#: meets the torso, within the gap at any angle.
SHOULDER_REACH = 0.10


def _side(name: str) -> int | None:
    """0 for a left joint, 1 for a right one (Anny's ".L"/".R", CMU's "Left"/"Right", SMPL's
    "left_"/"right_"), None otherwise."""
    if name.endswith(".L") or name.startswith(("Left", "left_")):
        return 0
    if name.endswith(".R") or name.startswith(("Right", "right_")):
        return 1
    return None


def shoulder_joints(body) -> tuple[int, int]:
    """The (left, right) joints that turn the whole arm of `body`'s rig (its proximal arm bones)."""
    from physdrape.body.poses import arm_bones

    is_distal, is_arm = arm_bones(body)
    found: dict[int, int] = {}
    for j in torch.nonzero(is_arm & ~is_distal)[:, 0].tolist():
        side = _side(body.joint_names[j])
        if side is not None:
            found.setdefault(side, j)
    if len(found) != 2:
        raise ValueError(f"cannot find both shoulders among the {body.rig!r} rig's joints")
    return found[0], found[1]


@torch.no_grad()
def abduction_angles(body, state: BodyState, *, gap: float = ARM_GAP) -> Tensor:
    """Per posed body of `state` (B bodies of `body`) and arm (left, right), the smallest whole
    degree up to `ANGLES_DEG[-1]` that puts the arm's measured vertices (`_arm_vertices`) `gap`
    [m] from the rest of the body, (B, 2) float64; where none does, the angle of `ANGLES_DEG`
    that leaves the arm farthest off (an arm held across the body may not clear it by turning
    out). The angles of `ANGLES_DEG` are tried a few at a time, in order, until every arm has
    one; then the degrees between the first that clears and the one before it."""
    from physdrape.body.poses import TORSO_LOCK, arm_sets, torso_surface

    arms = _arms(body, state)
    angles = torch.tensor(ANGLES_DEG, dtype=torch.float64)
    found = torch.zeros(state.batch_size, 2, dtype=torch.int64)
    best = torch.full((state.batch_size, 2), -torch.inf, dtype=torch.float64)  # the farthest off so far
    todo = torch.ones(state.batch_size, 2, dtype=torch.bool)
    with TORSO_LOCK:
        surface = torso_surface(body, arm_sets(body)[1], state.verts.to(torch.float32))
        for lo in range(0, len(ANGLES_DEG), _CHUNK):
            chunk = angles[lo:lo + _CHUNK]
            for side, off in enumerate(_nearest(surface, arms, [chunk, chunk])):  # (B, A) each
                farther = todo[:, side] & (off.amax(dim=1) > best[:, side])
                found[farther, side] = lo + off.argmax(dim=1)[farther]
                best[farther, side] = off.amax(dim=1)[farther]
                clear = off >= gap
                hit = todo[:, side] & clear.any(dim=1)
                found[hit, side] = lo + clear.to(torch.int8).argmax(dim=1)[hit]
                todo[hit, side] = False
            if not bool(todo.any()):
                break
        out = angles[found]
        cleared = ~todo & (found > 0)
        if bool(cleared.any()):  # the whole degrees below each first clearing angle, smallest first
            below = angles[(found - 1).clamp_min(0)]
            steps = torch.arange(1.0, float(ANGLES_DEG[1] - ANGLES_DEG[0]), dtype=torch.float64)
            fine = [below[:, side, None] + steps for side in range(2)]  # (B, S) per side
            for side, off in enumerate(_nearest(surface, arms, fine)):
                clear = (off >= gap) & cleared[:, side, None]
                hit = clear.any(dim=1)
                out[hit, side] = fine[side][hit, clear[hit].to(torch.int8).argmax(dim=1)]
    return out


def _nearest(surface, arms: list[tuple[Tensor, Tensor, Tensor, Tensor]], angles: list[Tensor]) -> list[Tensor]:
    """Per arm (`_arms`), the distance (B, A) float64 [m, CPU] from the rest of the body (the
    `surface`) of its measured vertex nearest to it, turned out by each of its angles [deg]
    ((A,) for every body or (B, A)): one search for both arms."""
    trials = [head[:, None, None] + torch.einsum("baij,bpj->bapi", abduction(direction, out, turn), arm)
              for (arm, head, direction, out), turn in zip(arms, angles)]  # per arm (B, A, P, 3)
    distance = standoff(surface, torch.cat([t.flatten(1, 2) for t in trials], dim=1))
    per_arm = distance.split([t.shape[1] * t.shape[2] for t in trials], dim=1)
    return [d.reshape(t.shape[:3]).amin(dim=2).cpu() for t, d in zip(trials, per_arm)]


#: Angles of `ANGLES_DEG` tried per search of the torso (most arms clear within the first few).
_CHUNK = 4


def _arms(body, state: BodyState) -> list[tuple[Tensor, Tensor, Tensor, Tensor]]:
    """Per arm (left, right) of the posed bodies: its measured vertices (every `STRIDE`-th of
    `_arm_vertices`) relative to its shoulder joint's head (B, P, 3), that head (B, 3), the arm's
    mean direction (B, 3) and the outward direction from the other shoulder (B, 3), float64."""
    query, sides = _arm_vertices(body)
    left, right = shoulder_joints(body)
    verts, heads = state.verts.to(torch.float64), state.joints.to(torch.float64)
    out = []
    for side, joint, other in ((0, left, right), (1, right, left)):
        arm = verts[:, query[sides == side][::STRIDE].to(verts.device)] - heads[:, joint, None]
        out.append((arm, heads[:, joint], arm.mean(dim=1), heads[:, joint] - heads[:, other]))
    return out


def standoff(surface, points: Tensor) -> Tensor:
    """Signed distance (B, N) float64 [m] of points (B, N, 3) to the posed bodies of `surface` (a
    `BodySurface` of B bodies), negative inside by the winding number of every point (one search
    for the closest face and the winding number together: no doubtful faces, normals or
    gradient)."""
    batch, n = points.shape[:2]
    body = torch.arange(batch, dtype=torch.int32, device=points.device).repeat_interleave(n)
    flat = points.reshape(-1, 3)
    face, inside = surface.search(flat.to(torch.float32).contiguous(), body, winding=True)
    corners = surface.faces[face] + (body.to(face) * surface.num_verts)[:, None]
    closest, _ = closest_point_on_indexed_triangles(flat.to(torch.float64), surface.verts.reshape(-1, 3).to(
        torch.float64), corners)
    distance = (flat.to(torch.float64) - closest).norm(dim=-1)
    return torch.where(inside, -distance, distance).reshape(batch, n)


def abduction(arm: Tensor, outward: Tensor, angles_deg: Tensor) -> Tensor:
    """World rotations (B, A, 3, 3) turning direction `arm` (B, 3) toward `outward` (B, 3) by each
    angle [deg] of `angles_deg`, (A,) for every body or (B, A), about the axis normal to both
    (about the body's front-to-back axis for an arm hanging at the side)."""
    axis = torch.linalg.cross(arm, outward)
    axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    angles = torch.deg2rad(angles_deg.to(arm)).expand(arm.shape[0], -1)
    rotvec = axis[:, None, :] * angles[..., None]
    return axis_angle_to_matrix(rotvec)


@torch.no_grad()
def clear_arms(body, state: BodyState, pose: Tensor, *, rows: Tensor | None = None,
               gap: float = ARM_GAP) -> tuple[Tensor, Tensor]:
    """`pose` (B, J, 3) axis-angles of `body`, posed as `state`, with each arm turned out by its
    `abduction_angles` (the body's pose convention: joint c's rotation D_c is in its parent's
    carried frame, so a world turn Q at the shoulder is D_c ← G_pᵀ Q G_p D_c), and those angles
    (B, 2) [deg] (left, right; 0: the arm is clear already and keeps its rotation). rows: the
    bodies (B,) bool to clear (None: all); the others keep their poses and get angles 0. The
    caller poses the bodies again where an angle is not 0."""
    angles = abduction_angles(body, state, gap=gap)
    if rows is not None:
        angles[~rows.cpu()] = 0.0
    if not bool((angles > 0).any()):
        return pose, angles
    out = pose.clone()
    rotations = pose_to_matrices(pose, body.num_joints).to(torch.float64)
    world = state.joint_rotations.to(torch.float64)
    for side, ((_, _, direction, outward), joint) in enumerate(zip(_arms(body, state), shoulder_joints(body))):
        todo = torch.nonzero(angles[:, side] > 0)[:, 0]
        if not todo.numel():
            continue
        turn = angles[todo, side].to(direction)[:, None]
        q = abduction(direction[todo], outward[todo], turn)[:, 0]  # (T, 3, 3)
        parent = body.parents[joint]
        carried = world[todo, parent] if parent >= 0 else torch.eye(3, dtype=q.dtype, device=q.device)
        local = carried.transpose(-1, -2) @ q @ carried @ rotations[todo, joint]
        out[todo, joint] = matrix_to_axis_angle(local).to(pose.dtype)
    return out, angles


def _arm_vertices(body) -> tuple[Tensor, Tensor]:
    """The measured arm vertices of `body`: those skinned mostly to an arm bone
    (`poses.arm_bones`) at least `SHOULDER_REACH` from their shoulder joint's head on the
    canonical body (a distance the arm's turns keep), and each one's side (0 left, 1 right);
    found once per body."""
    from physdrape.body.poses import arm_bones

    cache = body.__dict__.setdefault("_arm_clearance_cache", {})
    if "sides" not in cache:
        part = body.vertex_part()
        query = torch.nonzero(arm_bones(body)[1][part])[:, 0]
        of_joint = torch.tensor([-1 if _side(name) is None else _side(name) for name in body.joint_names])
        sides = of_joint[part[query]]
        rest = body(body.default_shape(1, dtype=torch.float64), body.rest_pose(1, dtype=torch.float64))
        heads = rest.joints[0, list(shoulder_joints(body))]  # (2, 3): left, right
        reach = (rest.verts[0, query] - heads[sides.clamp_min(0)]).norm(dim=-1)
        keep = (sides >= 0) & (reach >= SHOULDER_REACH)
        cache["query"], cache["sides"] = query[keep], sides[keep]
    return cache["query"], cache["sides"]
