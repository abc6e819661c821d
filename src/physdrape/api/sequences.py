"""Warm-started sequences: the frames of a motion draped in order, each from the last.

Frame `start` of a warm-started `Motion` is draped cold (the full model from its skinned X_init).
Each later frame t starts from the previous drape X*(t−1) carried along by the body: per garment
vertex i, with T_i(t) = Σ_j W_ij T_j(t) the body's skinning transforms blended by the garment's
transfer weights W (as `SkinningTransfer.apply` blends them),

    X_init(t) = T_i(t) T_i(t−1)⁻¹ X*(t−1),

then edge-stretch limited with the body held out, like the skinned X_init. Such frames depend on
their predecessor, so they are draped one by one after the batches of independent jobs.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import replace

import torch
from torch import Tensor

from physdrape.api.specs import BodyPose
from physdrape.api.types import Motion
from physdrape.body.model import BodyState
from physdrape.body.skinning_transfer import SkinningTransfer
from physdrape.geometry.proximity import BodySurface

_SEQUENCE_IDS = itertools.count(1)


def tag_frames(motion: Motion, poses: list[BodyPose]) -> list[BodyPose]:
    """Tag the frames of a warm-started multi-frame motion, so that `predecessors` chains them."""
    if not motion.warm_start or len(poses) < 2:
        return poses
    sequence = next(_SEQUENCE_IDS)
    mode = "solver" if motion.warm_start is True else str(motion.warm_start)
    return [replace(bp, sequence=(sequence, k, mode)) for k, bp in enumerate(poses)]


def predecessors(poses: Sequence[BodyPose], template_keys: Sequence[str]) -> list[int | None]:
    """Per job, the job it continues (consecutive frames of one warm-started motion on the same
    garment), or None for a job draped from its own skinned X_init."""
    prev: list[int | None] = [None] * len(poses)
    for i in range(1, len(poses)):
        a, b = poses[i - 1].sequence, poses[i].sequence
        if a is not None and b is not None and a[0] == b[0] and b[1] == a[1] + 1 \
                and template_keys[i - 1] == template_keys[i]:
            prev[i] = i - 1
    return prev


def blended_transforms(transfer: SkinningTransfer, state: BodyState) -> Tensor:
    """T(t): the body's skinning transforms blended per garment vertex, (V, 3, 4), for a state of
    batch 1, in the state's dtype."""
    return transfer.blended_transforms(state)[0]


def carried_init(transfer: SkinningTransfer, x_prev: Tensor, t_prev: Tensor, t_now: Tensor,
                 state: BodyState) -> Tensor:
    """X_init(t) = T(t) T(t−1)⁻¹ X*(t−1) per garment vertex, edge-stretch limited with the body of
    `state` (batch 1) held out. x_prev (V, 3) [m]; t_prev, t_now (V, 3, 4); in their dtype."""
    x_rest = torch.linalg.solve(t_prev[..., :3], (x_prev - t_prev[..., 3]).unsqueeze(-1))
    x = (t_now[..., :3] @ x_rest).squeeze(-1) + t_now[..., 3]
    body = BodySurface(state.verts[0].detach().to(x.dtype)[None], state.faces)
    return transfer.limit_stretch(x, body=body)
