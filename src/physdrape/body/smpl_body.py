"""SMPL / SMPL+H / SMPL-X bodies through the optional `smplx` package (model files never shipped).

The user passes the model file they licensed: ``.npz`` (preferred) or a legacy ``.pkl``. Pickles
are read through a restricted unpickler that accepts only numpy arrays, scipy sparse matrices and
chumpy arrays (converted to numpy without needing chumpy); anything else is refused. SMPL is
already y-up and in metres, so nothing is rotated.

Shape = β (B, num_betas); pose = θ, one axis-angle per joint, (B, J, 3) or SMPL's flat (B, 3J)
(J = 24 for SMPL: 72 values; 52 for SMPL+H; 55 for SMPL-X with flat hands and zero
expression). The pose corrective blend shapes are folded into `BodyState.vertex_transforms`
(translation part), so verts == T applied to rest_verts (= the shaped template) exactly.
"""

from __future__ import annotations

import io
import os
import pickle
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

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

SMPL_JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hand", "right_hand",
)
"""The 24 SMPL joints in θ order (SMPL+H / SMPL-X share the first 22)."""

REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")

_INSTALL_HINT = "the SMPL/SMPL-X backend needs the optional `smplx` package: pip install smplx"


def _import_smplx():
    try:
        import smplx
    except ImportError as e:
        raise ImportError(_INSTALL_HINT) from e
    return smplx


# ----------------------------------------------------------------------------------------------
# Restricted loading


class _ChumpyArray:
    """Stand-in for chumpy.ch.Ch while unpickling: keeps the pickled state, becomes numpy."""

    def __setstate__(self, state):
        self.__dict__.update(state if isinstance(state, dict) else {"_state": state})

    def to_numpy(self) -> np.ndarray:
        if "x" not in self.__dict__:
            raise pickle.UnpicklingError(
                "a chumpy object in the model file is not a plain array (no 'x' field); convert "
                "the model to .npz with chumpy installed (np.savez(path, **{k: np.array(v)}))"
            )
        return np.asarray(self.__dict__["x"])


_ALLOWED: dict[tuple[str, str], object] = {}


def _allowed_globals() -> dict[tuple[str, str], object]:
    if _ALLOWED:
        return _ALLOWED
    import codecs
    import copyreg

    import scipy.sparse as sp

    try:
        from numpy._core import multiarray as ma
    except ImportError:  # numpy < 2
        from numpy.core import multiarray as ma
    for mod in ("numpy.core.multiarray", "numpy._core.multiarray"):
        _ALLOWED[(mod, "_reconstruct")] = ma._reconstruct
        _ALLOWED[(mod, "scalar")] = ma.scalar
    _ALLOWED[("numpy", "ndarray")] = np.ndarray
    _ALLOWED[("numpy", "dtype")] = np.dtype
    for mod in ("copy_reg", "copyreg"):
        _ALLOWED[(mod, "_reconstructor")] = copyreg._reconstructor
    for mod in ("__builtin__", "builtins"):
        _ALLOWED[(mod, "object")] = object
    _ALLOWED[("_codecs", "encode")] = codecs.encode
    for kind in ("csc", "csr", "coo"):
        cls = getattr(sp, f"{kind}_matrix")
        for mod in (f"scipy.sparse.{kind}", f"scipy.sparse._{kind}", "scipy.sparse"):
            _ALLOWED[(mod, f"{kind}_matrix")] = cls
    return _ALLOWED


class RestrictedUnpickler(pickle.Unpickler):
    """Unpickles numpy arrays, scipy sparse matrices and chumpy arrays only."""

    def find_class(self, module: str, name: str):
        allowed = _allowed_globals()
        if (module, name) in allowed:
            return allowed[(module, name)]
        if module.split(".")[0] == "chumpy":
            return _ChumpyArray
        raise pickle.UnpicklingError(
            f"refusing to load {module}.{name} from a model pickle: only numpy arrays, scipy "
            "sparse matrices and chumpy arrays are allowed. If the file is a genuine SMPL model, "
            "convert it to .npz; otherwise it may be malicious"
        )


def _to_plain(value):
    if isinstance(value, _ChumpyArray):
        return value.to_numpy()
    return value


def load_model_file(path: str | os.PathLike) -> dict:
    """Load an SMPL-family model file (.npz, or .pkl through `RestrictedUnpickler`) as a dict."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(
            f"SMPL model file not found: {path}. SMPL/SMPL-X models are not shipped with "
            "PhysDrape: download them from https://smpl.is.tue.mpg.de (or smpl-x.is.tue.mpg.de) "
            "and pass the path of the .npz / .pkl file"
        )
    if path.suffix == ".npz":
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {k: z[k] for k in z.files}
        except ValueError:
            # Some official .npz files hold a few object arrays (metadata dicts): read the
            # numeric arrays only; an object entry would need pickle, which we refuse.
            with np.load(path, allow_pickle=False) as z:
                data = {}
                for k in z.files:
                    try:
                        data[k] = z[k]
                    except ValueError:
                        continue
    elif path.suffix == ".pkl":
        with open(path, "rb") as fh:
            raw = fh.read()
        data = RestrictedUnpickler(io.BytesIO(raw), encoding="latin1").load()
        if not isinstance(data, dict):
            raise pickle.UnpicklingError(f"{path}: expected a dict of arrays, got {type(data).__name__}")
        data = {k: _to_plain(v) for k, v in data.items()}
    else:
        raise ValueError(f"{path}: unknown model file type {path.suffix!r}; expected .npz or .pkl")
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise ValueError(f"{path} is not an SMPL-family model: missing keys {missing} (need {REQUIRED_KEYS})")
    return data


def _resolve(model_path: str | os.PathLike, gender: str) -> Path:
    p = Path(model_path)
    if p.is_dir():
        for sub in ("", "smpl", "smplx", "smplh"):
            for stem in (f"SMPL_{gender.upper()}", f"SMPLX_{gender.upper()}", f"SMPLH_{gender.upper()}"):
                for ext in (".npz", ".pkl"):
                    q = p / sub / f"{stem}{ext}"
                    if q.is_file():
                        return q
        raise FileNotFoundError(
            f"no SMPL model for gender {gender!r} in {p} (looked for SMPL[X|H]_{gender.upper()}.npz/.pkl); "
            "download the model files from https://smpl.is.tue.mpg.de and pass their path"
        )
    return p


# ----------------------------------------------------------------------------------------------
# The backend


class SMPLBody(BodyModel):
    """An SMPL-family body from a user-supplied model file.

    Args:
        model_path: the model file (.npz / .pkl) or a folder holding SMPL_{GENDER}.npz|pkl.
        gender: used only to pick the file in a folder.
        num_betas: number of shape coefficients β (default 10).

    ``rig`` is ``"smpl"`` for the whole family (the API keys its bodies and transfers by it).
    """

    rig = "smpl"

    def __init__(self, model_path: str | os.PathLike, *, gender: str = "neutral", num_betas: int = 10) -> None:
        smplx = _import_smplx()
        from smplx.utils import Struct

        path = _resolve(model_path, gender)
        data = load_model_file(path)
        m = smplx.SMPL(model_path=str(path), data_struct=Struct(**data), num_betas=num_betas,
                       dtype=torch.float64, create_betas=False, create_global_orient=False,
                       create_body_pose=False, create_transl=False)
        self.path = path
        self.num_betas = int(m.num_betas)
        self._v_template = m.v_template.detach()  # (V, 3)
        self._shapedirs = m.shapedirs.detach()  # (V, 3, NB)
        self._posedirs = m.posedirs.detach()  # (P, V*3)
        self._J_regressor = m.J_regressor.detach()  # (J, V)
        self._weights = m.lbs_weights.detach()  # (V, J)
        self._parents = tuple(int(p) for p in m.parents.tolist())
        self._levels = joint_levels(self._parents)
        self._faces = torch.as_tensor(np.asarray(m.faces, dtype=np.int64))
        self._table = vertex_face_table(self._faces, self._v_template.shape[0])
        self._cast: dict = {}

    @property
    def faces(self) -> Tensor:
        return self._faces

    @property
    def num_joints(self) -> int:
        return len(self._parents)

    @property
    def num_verts(self) -> int:
        return int(self._v_template.shape[0])

    @property
    def parents(self) -> tuple[int, ...]:
        return self._parents

    @property
    def joint_names(self) -> tuple[str, ...]:
        if self.num_joints == 24:
            return SMPL_JOINT_NAMES
        hands = tuple(f"{side}_hand_finger{k}" for side in ("left", "right") for k in range(15))
        if self.num_joints == 52:  # SMPL+H: 15 finger joints per hand
            return SMPL_JOINT_NAMES[:22] + hands
        if self.num_joints == 55:  # SMPL-X: jaw, eyes, then the SMPL+H fingers
            return SMPL_JOINT_NAMES[:22] + ("jaw", "left_eye", "right_eye") + hands
        return SMPL_JOINT_NAMES[:22] + tuple(f"joint{j}" for j in range(22, self.num_joints))

    @property
    def skinning_weights(self) -> Tensor:
        return self._weights

    def vertex_part(self) -> Tensor:
        """Index of each vertex's dominant joint (largest skinning weight), shape (V,) int64."""
        return self._weights.argmax(dim=1)

    def _tensors(self, dtype, device) -> dict:
        key = (dtype, device)
        if key not in self._cast:
            self._cast[key] = {
                k: getattr(self, "_" + k).to(device=device, dtype=dtype)
                for k in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights")
            }
        return self._cast[key]

    def default_shape(self, batch_size: int = 1, *, dtype: torch.dtype = torch.float32) -> Tensor:
        return torch.zeros(batch_size, self.num_betas, dtype=dtype)

    def rest_pose(self, batch_size: int = 1, *, dtype: torch.dtype = torch.float32) -> Tensor:
        """Zero θ: SMPL's T-pose, shape (B, J, 3)."""
        return torch.zeros(batch_size, self.num_joints, 3, dtype=dtype)

    def rest_verts(self, shape: Tensor) -> Tensor:
        check_batch(shape, "betas", (self.num_betas,))
        c = self._tensors(shape.dtype, shape.device)
        return c["v_template"] + torch.einsum("bl,vkl->bvk", shape, c["shapedirs"])

    def canonical_verts(self, *, dtype: torch.dtype = torch.float32) -> Tensor:
        return self._v_template.to(dtype)

    def __call__(self, shape: Tensor, pose: Tensor, *, transl: Tensor | None = None) -> BodyState:
        """Args: shape β (B, num_betas); pose θ (B, J, 3) / (B, 3J) / (B, J, 3, 3);
        transl (B, 3) [m] optional. Returns a `BodyState` (see `physdrape.body.model`)."""
        check_batch(shape, "betas", (self.num_betas,))
        R = pose_to_matrices(pose, self.num_joints, name="pose (θ)")
        if R.dtype != shape.dtype:
            raise TypeError(f"betas are {shape.dtype} but the pose is {R.dtype}; pass one dtype")
        shape, R = broadcast_batch(shape, R)
        B = shape.shape[0]
        c = self._tensors(shape.dtype, shape.device)
        rest = c["v_template"] + torch.einsum("bl,vkl->bvk", shape, c["shapedirs"])
        joints_rest = torch.einsum("jv,bvk->bjk", c["J_regressor"], rest)
        eye = torch.eye(3, dtype=R.dtype, device=R.device)
        pose_feature = (R[:, 1:] - eye).reshape(B, -1)
        offsets = (pose_feature @ c["posedirs"]).reshape(B, -1, 3)
        G, joints, bone_T = forward_kinematics(R, joints_rest, self._parents, levels=self._levels)
        if transl is not None:
            check_batch(transl, "transl", (3,), batch_size=B)
            bone_T = torch.cat([bone_T[..., :3], bone_T[..., 3:] + transl[:, None, :, None]], -1)
            joints = joints + transl[:, None]
        T = blend_transforms(c["weights"], bone_T)
        # Fold the pose correctives into the translation: T (rest + o) = [A | t + A o] rest.
        Ao = (T[..., :3] @ offsets.unsqueeze(-1)).squeeze(-1)
        T = torch.cat([T[..., :3], (T[..., 3] + Ao).unsqueeze(-1)], -1)
        verts = apply_transforms(T, rest)
        faces = self._faces.to(shape.device)
        return BodyState(
            verts=verts,
            faces=faces,
            normals=vertex_normals(verts, faces, table=self._table.to(shape.device)),
            rest_verts=rest,
            vertex_transforms=to_homogeneous(T),
            joints=joints,
            joint_rotations=G,
        )
