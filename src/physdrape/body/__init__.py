"""Body models (Anny default, SMPL/SMPL-X optional), poses, shapes and mocap retargeting.

World frame y-up, metres, the body facing +z. See `physdrape.body.model` for the shared
`BodyState` / `BodyModel` interface and the pose convention.
"""

from physdrape.body.anny_body import PHENOTYPE_NAMES, AnnyBody, check_phenotypes, get_anny_body
from physdrape.body.bvh import CMU_MAX_TO_MB, BVHMotion, load_bvh, retarget_bvh
from physdrape.body.model import BodyModel, BodyState, forward_kinematics, vertex_normals
from physdrape.body.poses import (
    PRESETS,
    PoseSamplerConfig,
    arm_torso_penetration,
    load_amass_npz,
    preset_pose,
    sample_poses,
)
from physdrape.body.shapes import sample_shapes
from physdrape.body.smpl_body import SMPLBody, load_model_file

__all__ = [
    "AnnyBody",
    "BVHMotion",
    "BodyModel",
    "BodyState",
    "CMU_MAX_TO_MB",
    "PHENOTYPE_NAMES",
    "PRESETS",
    "PoseSamplerConfig",
    "SMPLBody",
    "arm_torso_penetration",
    "check_phenotypes",
    "forward_kinematics",
    "get_anny_body",
    "load_amass_npz",
    "load_bvh",
    "load_model_file",
    "preset_pose",
    "retarget_bvh",
    "sample_poses",
    "sample_shapes",
    "vertex_normals",
]
