"""Arms lifted off the torso (`body.arm_clearance`): an arm hanging against the torso is turned out
at the shoulder by the smallest angle that clears the gap, an arm clear already keeps its pose."""

from __future__ import annotations

import pytest
import torch

from physdrape.body.arm_clearance import (
    ANGLES_DEG,
    ARM_GAP,
    STRIDE,
    _arm_vertices,
    abduction_angles,
    clear_arms,
    shoulder_joints,
)
from physdrape.body.poses import _set, arm_sets, arm_torso_penetration, preset_pose


def _arms_down(body) -> torch.Tensor:
    """Both upper arms swung 40° toward the torso from the rest A-pose: the arms press into it."""
    pose = body.rest_pose(1, dtype=torch.float64)
    _set(pose, body, "upperarm01.L", ez=-40)
    return pose


@pytest.mark.anny
def test_arms_clear_of_the_torso_keep_their_pose(anny_body):
    shape = anny_body.default_shape(1, dtype=torch.float64)
    pose = torch.cat([preset_pose(anny_body, name, dtype=torch.float64) for name in ("t-pose", "a-pose")])
    state = anny_body(shape, pose)
    out, angles = clear_arms(anny_body, state, pose)
    assert angles.tolist() == [[0.0, 0.0], [0.0, 0.0]]
    assert out is pose  # not even copied


@pytest.mark.anny
def test_an_arm_against_the_torso_is_turned_out_until_it_clears_the_gap(anny_body):
    shape = anny_body.default_shape(1, dtype=torch.float64)
    pose = _arms_down(anny_body)
    state = anny_body(shape, pose)
    out, angles = clear_arms(anny_body, state, pose)
    assert (angles > 0).all() and (angles < ANGLES_DEG[-1]).all()
    # only the shoulders turn
    changed = torch.nonzero((out - pose).abs().amax(dim=(0, 2)) > 0)[:, 0].tolist()
    assert changed == sorted(shoulder_joints(anny_body))
    after = anny_body(shape, out)
    assert abduction_angles(anny_body, after).tolist() == [[0.0, 0.0]]  # clear by the gap now
    assert int(arm_torso_penetration(after, anny_body)[0]) == 0
    # each arm's distal part stands off the rest of the body by the gap, measured on the posed body
    from physdrape.body.arm_clearance import standoff
    from physdrape.body.poses import TORSO_LOCK, torso_surface

    query, _ = _arm_vertices(anny_body)
    with TORSO_LOCK:
        surface = torso_surface(anny_body, arm_sets(anny_body)[1], after.verts.to(torch.float32))
        gap = standoff(surface, after.verts[:, query[::STRIDE]].to(torch.float64))
    assert float(gap.min()) >= ARM_GAP - 1e-4
    # the smallest whole degree: one degree less leaves some of the arm within the gap
    from physdrape.body.arm_clearance import _arms, _nearest
    from physdrape.body.poses import TORSO_LOCK as LOCK

    with LOCK:
        surface = torso_surface(anny_body, arm_sets(anny_body)[1], state.verts.to(torch.float32))
        near = _nearest(surface, _arms(anny_body, state), [angles[:, 0:1] - 1.0, angles[:, 1:2] - 1.0])
        at = _nearest(surface, _arms(anny_body, state), [angles[:, 0:1], angles[:, 1:2]])
    assert all(float(n.max()) < ARM_GAP for n in near) and all(float(a.min()) >= ARM_GAP for a in at)
    # a gap no turn reaches: the turn that leaves the arm farthest off, here the largest
    assert abduction_angles(anny_body, state, gap=1.0).tolist() == [[ANGLES_DEG[-1], ANGLES_DEG[-1]]]


@pytest.mark.anny
def test_the_turn_measured_is_the_turn_posed(anny_body):
    """The search turns the measured arm vertices rigidly about the shoulder's head; the pose it
    writes (D ← G_pᵀ Q G_p D in the rig's convention) puts them there (up to the few near the
    shoulder that are partly skinned to bones the turn leaves: a fraction of a millimetre)."""
    from physdrape.body.arm_clearance import _arms, abduction

    shape = anny_body.default_shape(1, dtype=torch.float64)
    pose = _arms_down(anny_body)
    state = anny_body(shape, pose)
    out, angles = clear_arms(anny_body, state, pose)
    after = anny_body(shape, out)
    query, sides = _arm_vertices(anny_body)
    for side, (arm, head, direction, outward) in enumerate(_arms(anny_body, state)):
        turn = abduction(direction, outward, angles[:, side:side + 1].to(direction))[:, 0]
        predicted = head[:, None] + arm @ turn.transpose(-1, -2)
        posed = after.verts[:, query[sides == side][::STRIDE]].to(torch.float64)
        torch.testing.assert_close(posed, predicted, rtol=0, atol=5e-4)


@pytest.mark.anny
def test_only_the_rows_asked_are_cleared(anny_body):
    shape = anny_body.default_shape(1, dtype=torch.float64)
    pose = torch.cat([_arms_down(anny_body), _arms_down(anny_body)])
    state = anny_body(shape, pose)
    out, angles = clear_arms(anny_body, state, pose, rows=torch.tensor([False, True]))
    assert angles[0].tolist() == [0.0, 0.0] and (angles[1] > 0).all()
    assert torch.equal(out[0], pose[0]) and not torch.equal(out[1], pose[1])
