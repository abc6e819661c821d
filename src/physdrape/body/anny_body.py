"""The Anny body model (PyPI `anny`, Apache-2.0), the default PhysDrape body.

Shape = Anny's phenotypes, pose = one rotation per bone of an Anny rig (see `physdrape.body.model`
for the convention). Anny is z-up with the body facing -y; everything is rotated ONCE on load
into the PhysDrape frame: y up, the body facing +z, its left side at +x, metres
(x, y, z)_physdrape = (x, z, -y)_anny.

Topologies (Anny names): ``anny`` = MakeHuman hm08 without helper geometry (13,718 vertices:
the skin, two eyeballs and the teeth/tongue block); ``makehuman`` = the full hm08 base mesh
(19,158 vertices, with the helper geometry `.mhclo` files may bind to). The collision surface
`AnnyBody.faces` is the skin only: the largest connected component of the ``anny`` topology,
13,348 vertices, a closed 2-manifold (0 boundary edges).

The first Anny build of a (rig, topology) is slow and is cached by Anny on disk
(``~/.cache/anny`` or ``$ANNY_CACHE_DIR``); what PhysDrape reads from it is cached again, and read
without importing Anny, by `body.anny_data`. This module keeps one copy of the body per process
(`get_anny_body`).
"""

from __future__ import annotations

import functools

import torch
from torch import Tensor

from physdrape.body.anny_data import load_anny_data, phenotype_coefficients
from physdrape.body.model import (
    BodyModel,
    BodyState,
    apply_transforms,
    blend_transforms,
    broadcast_batch,
    check_batch,
    forward_kinematics,
    joint_levels,
    pose_to_matrices,
    to_homogeneous,
    vertex_face_table,
    vertex_normals,
)

PHENOTYPE_NAMES: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")
"""Order of the shape vector (B, 6), values in [0, 1]. gender 0 = male, 1 = female; age uses
Anny's anchors newborn -1/3 (clamped to 0), baby 0, child 1/3, young adult 2/3, old 1 (so 0.5 is
a teenager); muscle, weight, height: min 0, average 0.5, max 1; proportions 0 = ideal,
1 = uncommon."""

NUM_HM08_VERTS = 19158
def check_phenotypes(shape: Tensor, *, name: str = "shape") -> None:
    """Raise a clear error unless shape is a finite (B, 6) float tensor with values in [0, 1]."""
    check_batch(shape, name, (len(PHENOTYPE_NAMES),))
    bad = (shape < 0) | (shape > 1)
    if bool(bad.any()):
        b, k = bad.nonzero()[0].tolist()
        raise ValueError(
            f"{name}: phenotype {PHENOTYPE_NAMES[k]!r} = {float(shape[b, k]):.4g} (batch {b}) is "
            f"outside [0, 1]; expected values in [0, 1] in the order {PHENOTYPE_NAMES}"
        )


class AnnyBody(BodyModel):
    """Anny as a PhysDrape body: shape (B, 6) phenotypes, pose (B, J, 3) axis-angle.

    Args:
        rig: ``"anny"`` (default; 104 bones, `joint_names`) or ``"cmu_mb"`` (the 31-bone CMU
            mocap skeleton with MotionBuilder names, the target of `physdrape.body.bvh`).

    Pose (see `physdrape.body.model`): local rotation of each bone about its head in the
    rest-pose world axes (y up, facing +z); joint 0 is the root (global orientation about the
    root head). Zero = Anny's rest pose, an A-pose. An optional `transl` (B, 3) [m] moves the
    whole body. Float32 and float64 inputs are supported (computation in the input dtype).
    """

    def __init__(self, *, rig: str = "anny") -> None:
        self.rig = rig
        self._data = load_anny_data(rig, "anny", True)
        self._levels = joint_levels(self._data.parents)
        self._cast: dict = {}

    # ----------------------------------------------------------------------------- metadata
    @property
    def faces(self) -> Tensor:
        """Triangles of the closed skin surface, shape (Fb, 3) int64."""
        return self._data.faces

    @property
    def num_verts(self) -> int:
        return int(self._data.template.shape[0])

    @property
    def num_faces(self) -> int:
        return int(self._data.faces.shape[0])

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Bone names of the rig, in pose order (J,)."""
        return self._data.bone_labels

    @property
    def parents(self) -> tuple[int, ...]:
        """Parent of each joint, -1 for the root."""
        return self._data.parents

    @property
    def num_joints(self) -> int:
        return len(self._data.bone_labels)

    @property
    def phenotype_names(self) -> tuple[str, ...]:
        return PHENOTYPE_NAMES

    @property
    def skinning_weights(self) -> Tensor:
        """Dense LBS weights of the surface vertices, shape (Vb, J) float64, rows sum to 1."""
        return self._data.weights

    @property
    def hm08_ids(self) -> Tensor:
        """Index in the MakeHuman hm08 base mesh (19,158 vertices) of each surface vertex, (Vb,)."""
        return self._data.hm08_ids

    def joint_index(self, name: str) -> int:
        try:
            return self._data.bone_labels.index(name)
        except ValueError:
            raise KeyError(f"unknown joint {name!r}; the {self.rig!r} rig has {self._data.bone_labels}") from None

    def vertex_part(self) -> Tensor:
        """The dominant bone of each surface vertex (argmax of its skinning weights), (Vb,)."""
        return self._data.weights.argmax(1)

    # ----------------------------------------------------------------------------- params
    def default_shape(self, batch_size: int = 1, *, dtype: torch.dtype = torch.float32) -> Tensor:
        """The canonical phenotypes (all 0.5), shape (B, 6)."""
        return torch.full((batch_size, len(PHENOTYPE_NAMES)), 0.5, dtype=dtype)

    def rest_pose(self, batch_size: int = 1, *, dtype: torch.dtype = torch.float32) -> Tensor:
        """Zero rotations = Anny's rest A-pose, shape (B, J, 3)."""
        return torch.zeros(batch_size, self.num_joints, 3, dtype=dtype)

    def shape_from_dict(self, values: dict[str, float], *, dtype: torch.dtype = torch.float32) -> Tensor:
        """A (1, 6) shape from phenotype names (missing ones at 0.5)."""
        unknown = set(values) - set(PHENOTYPE_NAMES)
        if unknown:
            raise ValueError(f"unknown phenotypes {sorted(unknown)}; expected names in {PHENOTYPE_NAMES}")
        shape = self.default_shape(1, dtype=dtype)
        for k, v in values.items():
            shape[0, PHENOTYPE_NAMES.index(k)] = float(v)
        check_phenotypes(shape)
        return shape

    # ----------------------------------------------------------------------------- forward
    def _tensors(self, dtype: torch.dtype, device: torch.device) -> dict:
        key = (dtype, device)
        if key not in self._cast:
            d = self._data
            c = {
                name: getattr(d, name).to(device=device, dtype=dtype)
                for name in ("template", "blend", "heads", "heads_blend", "weights")
            }
            if d.tails is not None:
                c["tails"] = d.tails.to(device=device, dtype=dtype)
                c["tails_blend"] = d.tails_blend.to(device=device, dtype=dtype)
            c["faces"] = d.faces.to(device)
            c["table"] = vertex_face_table(c["faces"], d.template.shape[0])
            self._cast[key] = c
        return self._cast[key]

    def blend_coefficients(self, shape: Tensor) -> Tensor:
        """Coefficients of the (compacted) phenotype blendshapes, shape (B, K)."""
        return phenotype_coefficients(self._data, shape, PHENOTYPE_NAMES)

    def rest_verts(self, shape: Tensor) -> Tensor:
        """Shaped surface in the rest pose [m], shape (B, Vb, 3)."""
        check_phenotypes(shape)
        c = self._tensors(shape.dtype, shape.device)
        coeff = self.blend_coefficients(shape)
        return c["template"] + (coeff @ c["blend"]).reshape(shape.shape[0], -1, 3)

    def rest_joints(self, shape: Tensor) -> Tensor:
        """Rest positions of the bone heads [m], shape (B, J, 3)."""
        check_phenotypes(shape)
        c = self._tensors(shape.dtype, shape.device)
        coeff = self.blend_coefficients(shape)
        return c["heads"] + (coeff @ c["heads_blend"]).reshape(shape.shape[0], -1, 3)

    def rest_tails(self, shape: Tensor) -> Tensor:
        """Rest positions of the bone tails [m] (rigs with tails, e.g. cmu_mb), shape (B, J, 3)."""
        check_phenotypes(shape)
        c = self._tensors(shape.dtype, shape.device)
        if "tails" not in c:
            raise ValueError(f"the {self.rig!r} rig has no bone tails")
        coeff = self.blend_coefficients(shape)
        return c["tails"] + (coeff @ c["tails_blend"]).reshape(shape.shape[0], -1, 3)

    def canonical_verts(self, *, dtype: torch.dtype = torch.float32) -> Tensor:
        """The canonical body (all phenotypes 0.5, rest A-pose) [m], shape (Vb, 3): a copy of the
        one formed on first use per dtype (each new garment's fit and checks ask for it)."""
        key = ("canonical", dtype)
        if key not in self._cast:
            self._cast[key] = self.rest_verts(self.default_shape(1, dtype=dtype))[0]
        return self._cast[key].clone()

    def __call__(self, shape: Tensor, pose: Tensor, *, transl: Tensor | None = None) -> BodyState:
        """Pose and shape a batch of bodies.

        Args:
            shape: phenotypes in [0, 1] in the order `PHENOTYPE_NAMES`, shape (B, 6).
            pose: (B, J, 3) axis-angle [rad] or (B, J, 3, 3) rotations, J = `num_joints`.
                A batch of 1 in either argument is broadcast against the other.
            transl: optional translation of the whole body [m], shape (B, 3).
        Returns:
            `BodyState` with verts, faces, normals, rest_verts, vertex_transforms (B, Vb, 4, 4),
            joints (B, J, 3) and joint_rotations (B, J, 3, 3).
        """
        check_phenotypes(shape)
        R = pose_to_matrices(pose, self.num_joints)
        if R.dtype != shape.dtype:
            raise TypeError(f"shape is {shape.dtype} but pose is {R.dtype}; pass one dtype")
        shape, R = broadcast_batch(shape, R)
        c = self._tensors(shape.dtype, shape.device)
        B = shape.shape[0]
        coeff = self.blend_coefficients(shape)
        rest = c["template"] + (coeff @ c["blend"]).reshape(B, -1, 3)
        heads = c["heads"] + (coeff @ c["heads_blend"]).reshape(B, -1, 3)
        G, joints, bone_T = forward_kinematics(R, heads, self._data.parents, levels=self._levels)
        if transl is not None:
            check_batch(transl, "transl", (3,), batch_size=B)
            bone_T = torch.cat([bone_T[..., :3], bone_T[..., 3:] + transl[:, None, :, None]], -1)
            joints = joints + transl[:, None]
        T = blend_transforms(c["weights"], bone_T)  # (B, V, 3, 4)
        verts = apply_transforms(T, rest)
        return BodyState(
            verts=verts,
            faces=c["faces"],
            normals=vertex_normals(verts, c["faces"], table=c["table"]),
            rest_verts=rest,
            vertex_transforms=to_homogeneous(T),
            joints=joints,
            joint_rotations=G,
        )

    # ----------------------------------------------------------------------------- hm08
    def hm08_verts(self, shape: Tensor) -> Tensor:
        """All 19,158 vertices of the MakeHuman hm08 base mesh (helpers included, no nudity
        edits), shaped, rest pose, PhysDrape frame [m], shape (B, 19158, 3), in hm08 order: the
        positions `.mhclo` garment files bind to. The first call may build Anny's ``makehuman``
        topology (slow, once per machine; then cached on disk)."""
        check_phenotypes(shape)
        d = load_anny_data("anny", "makehuman", False)
        template = d.template.to(shape)
        coeff = phenotype_coefficients(d, shape, PHENOTYPE_NAMES)
        verts = template + (coeff @ d.blend.to(shape)).reshape(shape.shape[0], -1, 3)
        out = verts.new_zeros(shape.shape[0], NUM_HM08_VERTS, 3)
        out[:, d.hm08_ids] = verts
        return out


@functools.lru_cache(maxsize=None)
def get_anny_body(rig: str = "anny") -> AnnyBody:
    """The process-wide `AnnyBody` for `rig` (built once, then shared)."""
    return AnnyBody(rig=rig)
