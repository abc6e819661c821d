"""The public Python API: drape garments onto Anny bodies with a trained PhysDrape model.

Example (the README snippet; `tests/api/test_api.py` runs it with a test model)::

    import physdrape

    draper = physdrape.Draper()  # loads the bundled model once
    # garments: "default" (bundled T-shirt), "tshirt:7" (generated), "shirt.obj", "suit.mhclo", (verts, faces)
    [res] = draper.drape("default", shape={"weight": 0.8, "gender": 0.3}, pose="stand", material="denim")
    print(res.verts.shape, res.metrics["b2g_percent"], res.timings["total_s"])
    res.save("out/")  # garment.obj/.ply, body.obj/.ply, drape.glb
    res.render("out/render.png")

Conventions: SI units, y-up metres; garment templates sit on the canonical Anny body (all
phenotypes 0.5, rest A-pose). One model pass plus `steps` explicit solver steps per batch.

SMPL / SMPL-X (model files never shipped): ``Draper(smpl_model="SMPL_NEUTRAL.npz")`` (or
``body=SMPLBody(...)``) drapes on that body instead: shape = β, pose = θ or AMASS frames
(``Motion("seq.npz", frames=(0, 10))``); garments must then be files authored on SMPL's canonical
body (β = 0, rest T-pose), since the bundled and generated garments are made for Anny.

Sequences: a multi-frame `Motion` is draped frame by frame with a warm start (each frame starts
from the previous frame's drape carried along by the body's motion, see `Motion`);
``Motion(..., warm_start=False)`` drapes every frame independently, as one batch.
"""

from __future__ import annotations

import hashlib
import re
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from physdrape.physics.material import Material
from physdrape.physics.presets import MATERIAL_PRESETS, material_preset

__all__ = ["GARMENT_CATEGORIES", "DrapeError", "DrapeResult", "Draper", "Motion", "default_checkpoint", "drape",
           "load_smpl_body"]

#: Categories of the procedural generator, usable as "category:seed" garment specs.
GARMENT_CATEGORIES = ("tshirt", "longsleeve", "tanktop", "croptop")
_GENERATED = re.compile(rf"^({'|'.join(GARMENT_CATEGORIES)}):(\d+)$")
_RANDOM_POSE = re.compile(r"^random:(\d+)$")
#: The pose used when none is given: a natural standing pose with the arms off the torso.
DEFAULT_POSE = "relaxed"


class DrapeError(ValueError):
    """Bad input to the draping API; the message says what was wrong and how to fix it."""


def default_checkpoint() -> Path:
    """Where the bundled model lives: ``physdrape/assets/models/cpu_default``."""
    return Path(str(files("physdrape") / "assets" / "models" / "cpu_default"))


@dataclass(frozen=True)
class Motion:
    """Frames of a motion used as poses.

    path: a ``.bvh`` file (CMU skeleton), retargeted onto Anny's ``cmu_mb`` rig; or an AMASS-style
        ``.npz`` (``poses`` (N, 3J) axis-angles [rad], optional ``betas``; read by
        `physdrape.body.poses.load_amass_npz`, z-up turned y-up, ``trans`` ignored) on an SMPL
        Draper (``Draper(smpl_model=...)``); its ``betas`` are the shape unless ``drape(shape=...)``
        gives one.
    frames: one frame index, or a (start, stop) half-open range.
    warm_start: for several frames, drape them in order, each starting from the previous frame's
        drape carried along by the body: per garment vertex i, with T_i(t) = sum_j W_ij T_j(t) the
        skinning transform of the body blended by the garment's transfer weights W (as in
        `SkinningTransfer.apply`), X_init(t) = T_i(t) T_i(t-1)^-1 X*(t-1) (then edge stretch
        limited like the skinned X_init). Frame `start` is draped cold (the full model from its own
        skinned X_init), so it equals the cold drape; the later frames are processed one by one,
        not as one batch. What runs on a warm frame:

        - ``"solver"`` (= True, the default): the explicit solver steps and the collision handler
          only (no network pass, f̂ = 0): the previous drape, carried along, keeps relaxing under
          the physics. Measured on CMU 131_01 with the bundled model (10 frames at 120 fps):
          mean E_strain 0.95 J vs 1.40 J cold and B2G 0.02 % vs 0.07 % (frames 300-309).
        - ``"model"``: the full model (network pass + solver + handler) on the carried X_init.
          The network is trained on skinned X_init and adds its correction again at every frame,
          so the drape drifts: on the same frames E_strain grew from 1.4 J to 22 J and B2G from
          0.1 % to 3.7 % within 10 frames. Kept for experiments.

        False: every frame from its own skinned X_init, all in one batch (PhysDrape is static: no
        velocities, no history).
    """

    path: str | Path
    frames: int | tuple[int, int] = 0
    warm_start: bool | str = True

    def __post_init__(self) -> None:
        if self.warm_start not in (True, False, "solver", "model"):
            raise DrapeError(f"Motion warm_start must be True/'solver', 'model' or False, got {self.warm_start!r}")


@dataclass
class DrapeResult:
    """One draped garment.

    Attributes:
        name: garment label.
        verts: draped garment positions X* [m], shape (V, 3) float (the Draper's dtype).
        faces: garment triangles, shape (F, 3) int64.
        body_verts: posed body [m], shape (Vb, 3); body_faces: (Fb, 3) int64.
        x_init: kinematic initialisation X_init [m], shape (V, 3).
        material: the fabric draped; pose: a label of the body pose.
        metrics: E_strain, E_bend [J, default material], B2G [%], close [%], residual force [N]
            and relative residual [per vertex weight] (see `physdrape.physics.metrics`).
        timings: wall seconds of the batch this garment was draped in, per phase, and
            ``batch_size``; ``per_garment_s`` = total / batch size.
        vertex_residual: ‖F_int‖ / (m_i g) per vertex at X* (V,) (free-hanging parts near 0).
        inside_faces: faces whose centroid is inside the body, (F,) bool (the B2G faces).
        convergence: per solver step t = 0..T: {"energy": E_strain+E_bend+E_grav [J],
            "force": Σ_i ‖F_int,i + f̂_i‖ [N]}; empty unless drape(keep_trace=True).
        init: how X_init was made: "skinning" (the garment skinned onto this body) or "warm"
            (the previous frame's drape carried along by the body's motion, see `Motion`).
    """

    name: str
    verts: np.ndarray
    faces: np.ndarray
    body_verts: np.ndarray
    body_faces: np.ndarray
    x_init: np.ndarray
    material: Material
    pose: str
    metrics: dict[str, float]
    timings: dict[str, float]
    vertex_residual: np.ndarray
    inside_faces: np.ndarray
    convergence: dict[str, list[float]] = field(default_factory=dict)
    init: str = "skinning"

    def to_trimesh(self, *, with_body: bool = False):
        """The garment as a `trimesh.Trimesh` (process=False keeps the topology); with_body: a Scene."""
        from physdrape.export import to_trimesh

        return to_trimesh(self, with_body=with_body)

    def save(self, directory: str | Path, formats: Sequence[str] = ("obj", "ply", "glb"), *,
             stem: str = "garment", overwrite: bool = False) -> list[Path]:
        """Write garment and body (``{stem}.obj/.ply``, ``body.obj/.ply``; ``drape.glb`` = one scene with both)
        into `directory`, each file atomically; refuses to overwrite unless `overwrite`."""
        from physdrape.export import save_result

        return save_result(self, directory, formats, stem=stem, overwrite=overwrite)

    def render(self, path: str | Path, *, mode: str = "shaded", size: int = 640) -> Path:
        """Write a PNG of body + garment; mode "shaded" or "residual" (force heatmap, B2G in red)."""
        from physdrape.render import render_result

        return render_result(self, path, mode=mode, size=size)

    def report(self) -> dict[str, Any]:
        """A JSON-able summary (metrics, timings, material, sizes)."""
        m = self.material
        return {
            "garment": self.name,
            "pose": self.pose,
            "num_verts": len(self.verts),
            "num_faces": len(self.faces),
            "material": {"mu_Pa": m.mu, "lam_Pa": m.lam, "k_bend_J": m.k_bend, "density_kg_m2": m.density},
            "E_strain_J": self.metrics["strain"],
            "E_bend_J": self.metrics["bend"],
            "B2G_percent": self.metrics["b2g_percent"],
            "close_percent": self.metrics["close_percent"],
            "residual_force_N": self.metrics["residual_force"],
            "residual_relative": self.metrics["residual_relative"],
            "init": self.init,
            "timings_s": self.timings,
        }


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass(frozen=True)
class _Template:
    name: str
    verts: np.ndarray  # (V, 3) float64
    faces: np.ndarray  # (F, 3) int64
    key: str


@dataclass(frozen=True)
class _BodyPose:
    rig: str
    pose: Tensor  # (1, J, 3) float64
    label: str
    shape: Tensor | None = None  # (1, S) float64: this pose's own body shape (AMASS betas), else the call's
    seq: tuple[int, int, str] | None = None  # (sequence id, frame, warm mode): frames of a warm-started Motion


class Draper:
    """Loads a PhysDrape model once and drapes batches of garments.

    Args:
        checkpoint: a checkpoint directory (model.safetensors + config.json) or a run directory
            (its ``latest``); None = the bundled model (`default_checkpoint`).
        steps: explicit solver steps T at inference (paper: 15).
        body: an `AnnyBody` (default: ``get_anny_body()``; loaded on first use), or an
            `SMPLBody` (``physdrape.body.smpl_body``): then every drape is on that SMPL body.
        smpl_model: path of an SMPL / SMPL+H / SMPL-X model file (.npz, or a legacy .pkl read by
            a restricted unpickler) or of a folder holding ``SMPL_{GENDER}.npz|pkl``: shorthand for
            ``body=SMPLBody(smpl_model, gender=smpl_gender)``. The model files are not shipped
            (https://smpl.is.tue.mpg.de). With an SMPL body: shape = β (`betas`), pose = θ
            (axis-angles per SMPL joint) or AMASS frames (`Motion` of an .npz), and garments must be
            .obj/.ply files authored on SMPL's canonical body (β = 0, zero pose).
        smpl_gender: picks the file when `smpl_model` is a folder.
        dtype: dtype of garments, bodies and the solver (the network keeps its own).
        check_pose: refuse (DrapeError) a pose whose arms pass through the torso
            (`body.poses.arm_torso_penetration`), instead of draping it silently.
        arm_contact_tolerance: arm vertices (of those the check samples, every 4th) allowed
            inside the body before a pose is refused: a hand resting on a hip is contact, an arm
            swung into the chest is not (it puts 50-150 inside).
    """

    def __init__(self, checkpoint: str | Path | None = None, *, steps: int = 15, body=None,
                 dtype: torch.dtype = torch.float32, check_pose: bool = True,
                 arm_contact_tolerance: int = 20, smpl_model: str | Path | None = None,
                 smpl_gender: str = "neutral") -> None:
        from physdrape.config_io import ConfigError, from_mapping
        from physdrape.model import PhysDrape
        from physdrape.model.config import ModelConfig
        from physdrape.train.checkpoint import CheckpointError, read_checkpoint

        if not isinstance(steps, int) or steps < 0:
            raise DrapeError(f"steps must be a non-negative integer, got {steps!r}")
        self.check_pose = check_pose
        self.arm_contact_tolerance = arm_contact_tolerance
        if dtype not in (torch.float32, torch.float64):
            raise DrapeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        path = Path(checkpoint).expanduser() if checkpoint is not None else default_checkpoint()
        if not path.exists():
            hint = ("the bundled model is not installed" if checkpoint is None else f"{path} does not exist")
            raise DrapeError(
                f"no PhysDrape model: {hint}. Train one with `physdrape train --config configs/cpu_default.yaml "
                f"--run-dir runs/cpu_default` and pass `--checkpoint runs/cpu_default` (API: "
                f"Draper(checkpoint=...)), or copy a checkpoint directory (model.safetensors + config.json) to "
                f"{default_checkpoint()}"
            )
        try:
            tensors, config = read_checkpoint(path)
            model_cfg = (config.get("train") or {}).get("model", config.get("model"))
            if model_cfg is None:
                raise CheckpointError(f"{path}/config.json has no train.model section: not a PhysDrape checkpoint")
            self.model_config = from_mapping(ModelConfig, model_cfg, where="train.model")
            self.model = PhysDrape(self.model_config)
            self.model.load_state_dict(tensors)
        except (CheckpointError, ConfigError, RuntimeError, KeyError) as exc:
            raise DrapeError(f"cannot load the PhysDrape checkpoint {path}: {exc}") from exc
        self.model.eval()
        self.checkpoint = path
        self.steps = steps
        self.dtype = dtype
        self._bodies: dict[str, Any] = {}
        if body is not None and smpl_model is not None:
            raise DrapeError("give either body=... or smpl_model=..., not both")
        if smpl_model is not None:
            body = load_smpl_body(smpl_model, gender=smpl_gender)
        if body is not None:
            if not hasattr(body, "rig"):
                raise DrapeError(f"body must be an AnnyBody or an SMPLBody, got {type(body).__name__}")
            self._bodies[body.rig] = body
        #: the SMPL body when this Draper drapes on SMPL (then Anny is never loaded), else None
        self.smpl = self._bodies.get("smpl")
        self._transfers: dict[tuple[str, str], Any] = {}
        self._garments: dict[str, Any] = {}
        self._templates: dict[str, _Template] = {}

    # ------------------------------------------------------------------ inputs
    def body(self, rig: str = "anny"):
        """The Anny body of `rig` ("anny" for presets/random poses, "cmu_mb" for BVH), cached;
        "smpl": the SMPL body given to the Draper."""
        if rig == "smpl" and rig not in self._bodies:
            raise DrapeError("this Draper has no SMPL body: create it with Draper(smpl_model=PATH) "
                             "(CLI: --smpl-model FILE)")
        if rig not in self._bodies:
            from physdrape.body.anny_body import get_anny_body

            self._bodies[rig] = get_anny_body(rig)
        return self._bodies[rig]

    def garment(self, spec) -> _Template:
        """Resolve a garment spec: "default", "category:seed", a path (.obj/.ply/.mhclo), a
        (verts (V, 3) [m], faces (F, 3)) pair, or an object with ``.verts``/``.faces``."""
        from physdrape.geometry.mesh import MeshError

        if isinstance(spec, (str, Path)):
            text = str(spec)
            if self.smpl is not None and (text == "default" or _GENERATED.match(text)
                                          or text.lower().endswith(".mhclo")):
                raise DrapeError(
                    f"garment {text!r} is made for the Anny body and does not fit SMPL: with an SMPL body, give a "
                    "garment file (.obj/.ply, metres, y-up) authored on SMPL's canonical body (β = 0, zero pose "
                    "= T-pose); the bundled default, the generated CATEGORY:SEED garments and .mhclo are Anny-only")
            if text in self._templates:
                return self._templates[text]
            try:
                if text == "default":
                    from physdrape.garments import default_garment

                    g = default_garment()
                elif _GENERATED.match(text):
                    from physdrape.garments import generate_valid_garment

                    category, seed = text.split(":")
                    g, _ = generate_valid_garment(category, int(seed))
                else:
                    p = Path(text).expanduser()
                    if not p.is_file():
                        raise DrapeError(
                            f"garment {text!r} is neither a file nor 'default' nor CATEGORY:SEED with CATEGORY in "
                            f"{', '.join(GARMENT_CATEGORIES)} (e.g. tshirt:7)")
                    suffix = p.suffix.lower()
                    if suffix == ".mhclo":
                        from physdrape.garments import load_mhclo

                        g = load_mhclo(p)
                    elif suffix in (".obj", ".ply"):
                        from physdrape.garments import load_template

                        g = load_template(p)
                    else:
                        raise DrapeError(f"garment file {p} has an unsupported extension {suffix!r}: use .obj, .ply "
                                         "(metres, y-up, on the canonical body) or .mhclo")
            except (MeshError, DrapeError):
                raise
            except (OSError, ValueError) as exc:
                raise DrapeError(f"cannot load garment {text!r}: {exc}") from exc
            t = self._template(g.name if text not in ("default",) else "tshirt_default", g.verts, g.faces)
            self._templates[text] = t
            return t
        if isinstance(spec, _Template):
            return spec
        if isinstance(spec, tuple) and len(spec) == 2:
            return self._template("garment", *spec)
        if hasattr(spec, "verts") and hasattr(spec, "faces"):
            return self._template(str(getattr(spec, "name", "garment")), spec.verts, spec.faces)
        raise DrapeError(f"cannot interpret garment {type(spec).__name__}: give a path, 'default', CATEGORY:SEED, "
                         "a (verts, faces) pair or an object with .verts and .faces")

    def _template(self, name: str, verts, faces) -> _Template:
        from physdrape.geometry.mesh import check_mesh

        v = np.asarray(verts.detach().cpu() if isinstance(verts, Tensor) else verts, dtype=np.float64)
        f = np.asarray(faces.detach().cpu() if isinstance(faces, Tensor) else faces)
        check_mesh(v, f, name=name)
        extent = float(np.ptp(v, axis=0).max())
        if extent > 3.0:
            raise DrapeError(f"garment {name!r} is {extent:.3g} units across: PhysDrape needs metres "
                             "(scale by 0.01 for cm, 0.1 for dm, 0.001 for mm)")
        f = f.astype(np.int64)
        return _Template(name=name, verts=v, faces=f, key=_digest(v, f))

    def shape(self, spec=None) -> Tensor:
        """Phenotypes (1, 6) float64 from None (canonical), a {name: value} dict or an array of 6;
        on an SMPL Draper: β (see `betas`)."""
        if self.smpl is not None:
            return self.betas(spec)
        from physdrape.body.anny_body import PHENOTYPE_NAMES

        body = self.body("anny")
        try:
            if spec is None:
                return body.default_shape(1, dtype=torch.float64)
            if isinstance(spec, dict):
                return body.shape_from_dict(spec, dtype=torch.float64)
            t = torch.as_tensor(np.asarray(spec, dtype=np.float64)).reshape(-1)
            if t.numel() != len(PHENOTYPE_NAMES):
                raise DrapeError(f"shape must have {len(PHENOTYPE_NAMES)} phenotypes {PHENOTYPE_NAMES}, got {t.numel()}")
            from physdrape.body.anny_body import check_phenotypes

            check_phenotypes(t[None])
            return t[None]
        except DrapeError:
            raise
        except (ValueError, TypeError) as exc:
            raise DrapeError(f"bad shape: {exc}") from exc

    def betas(self, spec=None) -> Tensor:
        """SMPL shape β (1, num_betas) float64 from None (β = 0, the canonical body) or up to
        num_betas values (fewer are padded with zeros)."""
        body = self.body("smpl")
        nb = body.num_betas
        if spec is None:
            return torch.zeros(1, nb, dtype=torch.float64)
        if isinstance(spec, dict):
            raise DrapeError("an SMPL body is shaped by β, not by Anny phenotypes: give shape=[b1, b2, ...] "
                             f"(up to {nb} values; CLI --betas b1,b2,...)")
        try:
            arr = np.asarray(spec.detach().cpu() if isinstance(spec, Tensor) else spec, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise DrapeError(f"bad SMPL shape β: {exc}; give up to {nb} numbers") from None
        if arr.size == 0 or arr.size > nb:
            raise DrapeError(f"SMPL shape β has {arr.size} values, the model {nb}: give 1..{nb} values "
                             "(missing ones are 0)")
        if not np.isfinite(arr).all():
            raise DrapeError("SMPL shape β contains NaN/inf")
        if np.abs(arr).max() > 10:
            raise DrapeError(f"SMPL shape β = {arr.tolist()} has |β| > 10: β are standard deviations of the "
                             "shape space (typically within ±3)")
        out = torch.zeros(1, nb, dtype=torch.float64)
        out[0, :arr.size] = torch.from_numpy(arr)
        return out

    def _smpl_poses(self, spec) -> list[_BodyPose]:
        body = self.body("smpl")
        J = body.num_joints
        if spec is None or (isinstance(spec, str) and spec in ("rest", "t-pose")):
            return [_BodyPose("smpl", body.rest_pose(1, dtype=torch.float64), "rest")]
        if isinstance(spec, Motion):
            return self._motion_poses(spec)
        if isinstance(spec, str):
            raise DrapeError(f"pose {spec!r}: the named presets and random:SEED are defined for Anny; on an SMPL "
                             f"body give θ, axis-angles [rad] of shape ({J}, 3) or ({3 * J},) (or N of them), "
                             "'rest', or AMASS frames Motion('seq.npz', frames=...)")
        try:
            arr = torch.as_tensor(np.asarray(spec.detach().cpu() if isinstance(spec, Tensor) else spec,
                                             dtype=np.float64))
        except (TypeError, ValueError) as exc:
            raise DrapeError(f"bad SMPL pose θ: {exc}") from None
        if arr.dim() == 1 and arr.numel() == 3 * J:
            arr = arr.reshape(1, J, 3)
        elif arr.dim() == 2 and arr.shape == (J, 3):
            arr = arr[None]
        elif arr.dim() == 2 and arr.shape[1] == 3 * J:
            arr = arr.reshape(-1, J, 3)
        if arr.dim() != 3 or arr.shape[1:] != (J, 3) or arr.shape[0] == 0:
            raise DrapeError(f"SMPL pose θ must be axis-angles [rad] of shape ({J}, 3) or ({3 * J},) for this "
                             f"{J}-joint model (or (N, {J}, 3) / (N, {3 * J})), got {tuple(arr.shape)}")
        if not torch.isfinite(arr).all():
            raise DrapeError("SMPL pose θ contains NaN/inf")
        return [_BodyPose("smpl", arr[i:i + 1], f"theta[{i}]") for i in range(arr.shape[0])]

    def poses(self, spec=None) -> list[_BodyPose]:
        """Poses from None (the default preset), a preset name, "random:SEED", an array (J, 3) or
        (N, J, 3) axis-angle [rad] on the "anny" rig, or a `Motion` (BVH frames).

        On an SMPL Draper: None / "rest" (zero θ, the T-pose), θ as (J, 3), (3J,), (N, J, 3) or
        (N, 3J) axis-angles [rad], or a `Motion` of an AMASS .npz."""
        from physdrape.body.poses import PRESETS, preset_pose, sample_poses

        if self.smpl is not None:
            return self._smpl_poses(spec)
        if spec is None:
            spec = DEFAULT_POSE
        if isinstance(spec, Motion):
            return self._motion_poses(spec)
        if isinstance(spec, str):
            m = _RANDOM_POSE.match(spec)
            if m:
                body = self.body("anny")
                return [_BodyPose("anny", sample_poses(body, 1, seed=int(m.group(1)), dtype=torch.float64), spec)]
            if spec not in PRESETS:
                raise DrapeError(f"unknown pose {spec!r}; choose one of {', '.join(PRESETS)}, random:SEED, or a BVH file")
            return [_BodyPose("anny", preset_pose(self.body("anny"), spec, dtype=torch.float64), spec)]
        body = self.body("anny")
        arr = torch.as_tensor(np.asarray(spec.detach().cpu() if isinstance(spec, Tensor) else spec, dtype=np.float64))
        if arr.dim() == 2:
            arr = arr[None]
        if arr.dim() != 3 or arr.shape[1:] != (body.num_joints, 3):
            raise DrapeError(f"pose arrays must be axis-angles of shape ({body.num_joints}, 3) or "
                             f"(N, {body.num_joints}, 3) for the 'anny' rig, got {tuple(arr.shape)}")
        if not torch.isfinite(arr).all():
            raise DrapeError("pose array contains NaN/inf")
        return [_BodyPose("anny", arr[i:i + 1], f"pose[{i}]") for i in range(arr.shape[0])]

    @staticmethod
    def _frame_range(motion: Motion, n: int, name: str) -> tuple[int, int]:
        frames = motion.frames
        ok = (isinstance(frames, (int, np.integer)) and not isinstance(frames, bool)) or (
            isinstance(frames, (tuple, list)) and len(frames) == 2 and all(isinstance(f, (int, np.integer))
                                                                           for f in frames))
        if not ok:
            raise DrapeError(f"Motion frames must be a frame index or a (start, stop) pair, got {frames!r}")
        start, stop = (int(frames), int(frames) + 1) if not isinstance(frames, (tuple, list)) else map(int, frames)
        if not 0 <= start < stop <= n:
            raise DrapeError(f"frames {motion.frames} out of range: {name} has {n} frames (0..{n - 1}); "
                             "give a frame index or START:STOP with 0 <= START < STOP <= number of frames")
        return start, stop

    def _sequence(self, motion: Motion, poses: list[_BodyPose]) -> list[_BodyPose]:
        """Tag the frames of a warm-started multi-frame motion (`drape` chains them)."""
        if not motion.warm_start or len(poses) < 2:
            return poses
        self._seq_counter = getattr(self, "_seq_counter", 0) + 1
        mode = "solver" if motion.warm_start is True else motion.warm_start
        return [_BodyPose(bp.rig, bp.pose, bp.label, bp.shape, (self._seq_counter, k, mode))
                for k, bp in enumerate(poses)]

    def _amass_poses(self, motion: Motion, path: Path) -> list[_BodyPose]:
        from physdrape.body.poses import load_amass_npz

        body = self.body("smpl")
        try:
            seq = load_amass_npz(path, num_joints=body.num_joints, num_betas=body.num_betas, dtype=torch.float64)
        except (ValueError, OSError, EOFError) as exc:  # np.load raises several types on bad files
            raise DrapeError(f"cannot read AMASS file {path}: {exc}") from None
        pose, betas = seq["pose"], seq["betas"]
        n = pose.shape[0]
        if n == 0:
            raise DrapeError(f"AMASS file {path.name} has no frames (poses is empty)")
        start, stop = self._frame_range(motion, n, path.name)
        pose = pose[start:stop]
        if not torch.isfinite(pose).all():
            bad = int((~torch.isfinite(pose)).flatten(1).any(1).nonzero()[0, 0]) + start
            raise DrapeError(f"AMASS file {path.name}: poses of frame {bad} contain NaN/inf; choose other frames")
        if not torch.isfinite(betas).all():
            raise DrapeError(f"AMASS file {path.name}: betas contain NaN/inf; fix the file or pass shape=β")
        shape = betas.reshape(1, -1)
        return [_BodyPose("smpl", pose[i:i + 1], f"{path.name}#{start + i}", shape) for i in range(stop - start)]

    def _motion_poses(self, motion: Motion) -> list[_BodyPose]:
        from physdrape.body.bvh import load_bvh, retarget_bvh

        path = Path(motion.path).expanduser()
        suffix = path.suffix.lower()
        if self.smpl is not None:
            if suffix != ".npz":
                raise DrapeError(f"motion {path.name}: an SMPL body takes AMASS .npz frames (poses, betas); BVH "
                                 "files are retargeted onto Anny only (use a Draper without smpl_model)")
            if not path.is_file():
                raise DrapeError(f"AMASS file not found: {path}")
            return self._sequence(motion, self._amass_poses(motion, path))
        if suffix == ".npz":
            raise DrapeError(f"motion {path.name}: AMASS .npz frames are SMPL poses; create the Draper with "
                             "smpl_model=PATH (CLI: --smpl-model FILE --amass FILE)")
        if not path.is_file():
            raise DrapeError(f"BVH file not found: {path}")
        try:
            bvh = load_bvh(path)
        except Exception as exc:  # the parser raises several types on malformed files
            raise DrapeError(f"cannot read BVH {path}: {exc}") from exc
        start, stop = self._frame_range(motion, bvh.num_frames, path.name)
        body = self.body("cmu_mb")
        try:
            ret = retarget_bvh(bvh, body, frames=slice(start, stop))
        except ValueError as exc:
            raise DrapeError(f"cannot retarget {path.name} onto Anny: {exc}") from exc
        return self._sequence(motion, [_BodyPose("cmu_mb", ret.pose[i:i + 1].to(torch.float64),
                                                 f"{path.name}#{start + i}") for i in range(ret.pose.shape[0])])

    @staticmethod
    def material(spec=None) -> Material:
        """A `Material` from None (cotton), a preset name (`MATERIAL_PRESETS`) or a Material."""
        if spec is None:
            return MATERIAL_PRESETS["cotton"]
        if isinstance(spec, Material):
            return spec
        if isinstance(spec, str):
            try:
                return material_preset(spec)
            except ValueError as exc:
                raise DrapeError(str(exc)) from None
        raise DrapeError(f"material must be a preset name ({', '.join(MATERIAL_PRESETS)}) or a Material, "
                         f"got {type(spec).__name__}")

    def transfer(self, template: _Template, rig: str):
        """The garment's `SkinningTransfer` onto `rig` (fitted once, ~0.35 s, then cached)."""
        key = (template.key, rig)
        if key not in self._transfers:
            from physdrape.body.skinning_transfer import SkinningTransfer

            body = self.body(rig)
            self._transfers[key] = SkinningTransfer.fit(
                body.canonical_verts(dtype=torch.float64), body.faces,
                torch.from_numpy(template.verts), torch.from_numpy(template.faces))
        return self._transfers[key]

    def _cloth_garment(self, template: _Template):
        if template.key not in self._garments:
            from physdrape.geometry.garment import Garment

            self._garments[template.key] = Garment.from_mesh(template.verts, template.faces, name=template.name,
                                                             dtype=self.dtype)
        return self._garments[template.key]

    # ------------------------------------------------------------------ draping
    def drape(self, garments, *, shape=None, pose=None, material=None, refine: bool = False,
              steps: int | None = None, keep_trace: bool = False, batch_size: int = 8, progress: bool = False,
              refine_iters: int = 30, refine_time_s: float = 60.0) -> list[DrapeResult]:
        """Drape garments onto a shaped, posed Anny body (or the Draper's SMPL body).

        Args:
            garments: one garment spec or a list (see `garment`).
            shape: phenotypes: None (canonical, all 0.5), a dict ({"weight": 0.8}; missing at 0.5),
                or 6 values in [0, 1] in the order `PHENOTYPE_NAMES`. SMPL: β, up to num_betas
                values (padded with zeros); None = β = 0, or the betas of AMASS frames.
            pose: one pose spec (see `poses`) or a list; a spec may expand to several frames.
                A multi-frame `Motion` with warm_start (the default) is draped frame by frame,
                each frame from the previous frame's drape (see `Motion`); its first frame, and
                every other job, from the skinned X_init in batches.
            material: a preset name or `Material`, or a list (one per job).
            steps: solver steps T for this call (default: the Draper's `steps`).
            refine: polish each drape with the physics oracle (`physics.relax`, projected Newton,
                penalty contact; at most `refine_iters` iterations / `refine_time_s` seconds per batch).
            keep_trace: record the solver's energy and force per step (`DrapeResult.convergence`).
            batch_size: garments per model call; progress: show a tqdm bar over batches.

        Jobs are the broadcast of garments × poses × materials (each list of length 1 or N).

        Returns:
            one `DrapeResult` per job, in order.
        """
        g_specs = garments if isinstance(garments, list) else [garments]
        p_specs = pose if isinstance(pose, list) else [pose]
        m_specs = material if isinstance(material, list) else [material]
        if not g_specs:
            raise DrapeError("no garments given")
        if batch_size < 1:
            raise DrapeError(f"batch_size must be ≥ 1, got {batch_size}")
        if steps is not None and (not isinstance(steps, int) or steps < 0):
            raise DrapeError(f"steps must be a non-negative integer, got {steps!r}")
        steps = self.steps if steps is None else steps
        templates = [self.garment(g) for g in g_specs]
        body_poses = [bp for p in p_specs for bp in self.poses(p)]
        if shape is not None:  # an explicit shape overrides the betas stored in AMASS frames
            body_poses = [bp if bp.shape is None else _BodyPose(bp.rig, bp.pose, bp.label, None, bp.seq)
                          for bp in body_poses]
        materials = [self.material(m) for m in m_specs]
        shape_t = self.shape(shape)
        lengths = {len(templates), len(body_poses), len(materials)} - {1}
        if len(lengths) > 1:
            raise DrapeError(f"cannot broadcast {len(templates)} garments, {len(body_poses)} poses and "
                             f"{len(materials)} materials: give lists of length 1 or of one common length")
        n = max(len(templates), len(body_poses), len(materials))
        jobs = [(templates[i % len(templates)], body_poses[i % len(body_poses)], materials[i % len(materials)])
                for i in range(n)]
        # Warm start: a job continues the previous one when both are consecutive frames of one
        # warm-started Motion on the same garment; such jobs run one by one after the cold ones.
        prev: list[int | None] = [None] * n
        for i in range(1, n):
            a, b = jobs[i - 1][1].seq, jobs[i][1].seq
            if a is not None and b is not None and a[0] == b[0] and b[1] == a[1] + 1 \
                    and jobs[i - 1][0].key == jobs[i][0].key:
                prev[i] = i - 1
        out: dict[int, DrapeResult] = {}
        affines: dict[int, Tensor] = {}
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=n, unit="garment", desc="draping")
        kw = {"steps": steps, "refine": refine, "keep_trace": keep_trace, "refine_iters": refine_iters,
                  "refine_time_s": refine_time_s}
        cold = [i for i in range(n) if prev[i] is None]
        for c in range(0, len(cold), batch_size):
            chunk = cold[c:c + batch_size]
            # one rig per model call (bodies in a BodySurface share a topology and a rig)
            for rig in dict.fromkeys(jobs[i][1].rig for i in chunk):
                part = [i for i in chunk if jobs[i][1].rig == rig]
                res, aff = self._drape_batch([jobs[i] for i in part], shape_t, **kw)
                out.update(zip(part, res))
                affines.update((i, a) for i, a in zip(part, aff) if a is not None)
                if bar is not None:
                    bar.update(len(part))
        for i in range(n):
            p = prev[i]
            if p is None:
                continue
            warm = (torch.from_numpy(out[p].verts).to(torch.float64), affines.pop(p))
            [res], [aff] = self._drape_batch([jobs[i]], shape_t, warm=[warm], physics_only=jobs[i][1].seq[2] == "solver",
                                             **kw)
            out[i], affines[i] = res, aff
            if bar is not None:
                bar.update(1)
        if bar is not None:
            bar.close()
        return [out[i] for i in range(n)]

    def _blended_affine(self, template: _Template, rig: str, state) -> Tensor:
        """The body's skinning transforms blended per garment vertex (state of batch 1), (V, 3, 4) float64."""
        return self.transfer(template, rig).blended_transforms(state)[0].to(torch.float64)

    def _warm_init(self, template: _Template, rig: str, x_prev: Tensor, a_prev: Tensor, a_now: Tensor,
                   state) -> Tensor:
        """X_init(t) = T(t) T(t-1)^-1 X*(t-1) per garment vertex, then edge-stretch limited with
        the body (`state`, batch 1) held out, like the skinned X_init (float64, (V, 3))."""
        x_rest = torch.linalg.solve(a_prev[..., :3], (x_prev - a_prev[..., 3]).unsqueeze(-1))
        x = (a_now[..., :3] @ x_rest).squeeze(-1) + a_now[..., 3]
        from physdrape.geometry.proximity import BodySurface

        body = BodySurface(state.verts[0].detach().to(x.dtype)[None], state.faces)
        return self.transfer(template, rig).limit_stretch(x, body=body)

    @staticmethod
    def _refuse_penetrating_poses(state, body, labels: list[str], tolerance: int) -> None:
        """A static drape cannot resolve cloth pinched between arm and torso: refuse such poses."""
        from physdrape.body.poses import arm_torso_penetration

        counts = arm_torso_penetration(state, body).tolist()
        bad = [f"{label} ({count} arm vertices inside the body)" for label, count in zip(labels, counts) if count > tolerance]
        if bad:
            raise DrapeError(
                f"pose drives the arms through the torso: {'; '.join(bad)}. PhysDrape drapes static poses with "
                "the arms clear of the body: choose another pose or frame (or Draper(check_pose=False) to drape anyway)"
            )

    @torch.no_grad()
    def _drape_batch(self, jobs, shape: Tensor, *, steps: int, refine: bool, keep_trace: bool, refine_iters: int,
                     refine_time_s: float, warm: list | None = None,
                     physics_only: bool = False) -> tuple[list[DrapeResult], list[Tensor | None]]:
        """Drape one batch. warm: per job None (X_init by skinning) or (X*(t-1) (V, 3), T(t-1)
        (V, 3, 4)) for a warm start; physics_only: skip the network (solver steps with f̂ = 0 and
        the collision handler only). Returns the results and, for jobs of a warm-started motion,
        the blended transforms T(t) (else None) for the next frame."""
        from physdrape.body.model import BodyState
        from physdrape.physics.metrics import drape_metrics
        from physdrape.geometry.garment import GarmentBatch
        from physdrape.geometry.proximity import BodySurface
        from physdrape.model import DrapeInput
        from physdrape.physics import Cloth, energy_terms, internal_forces

        t0 = time.perf_counter()
        rig = jobs[0][1].rig
        body = self.body(rig)
        # bodies: one per distinct pose in the batch
        labels = list(dict.fromkeys(id(job[1]) for job in jobs))
        poses = {id(job[1]): job[1] for job in jobs}
        pose_t = torch.cat([poses[k].pose for k in labels]).to(torch.float64)
        shapes = torch.cat([shape if poses[k].shape is None else poses[k].shape for k in labels]).to(torch.float64)
        state = body(shapes, pose_t)
        from physdrape.body.poses import _ARM_BONES

        if self.check_pose and getattr(body, "rig", None) in _ARM_BONES:
            self._refuse_penetrating_poses(state, body, [poses[k].label for k in labels], self.arm_contact_tolerance)
        t1 = time.perf_counter()
        x_init, garments, mats, body_ids, affines = [], [], [], [], []
        for k, (template, bp, mat) in enumerate(jobs):
            b = labels.index(id(bp))
            single = BodyState(verts=state.verts[b:b + 1], faces=state.faces, normals=torch.empty(0),
                               rest_verts=state.rest_verts[b:b + 1],
                               vertex_transforms=state.vertex_transforms[b:b + 1])
            a_now = self._blended_affine(template, rig, single) if bp.seq is not None else None
            affines.append(a_now)
            if warm is not None and warm[k] is not None:
                x_prev, a_prev = warm[k]
                if a_now is None:
                    a_now = self._blended_affine(template, rig, single)
                x_init.append(self._warm_init(template, rig, x_prev, a_prev, a_now, single).to(self.dtype))
            else:
                x_init.append(self.transfer(template, rig).apply(single)[0].to(self.dtype))
            garments.append(self._cloth_garment(template))
            mats.append(mat)
            body_ids.append(b)
        batch = GarmentBatch.pack(garments)
        cloth = Cloth.build(batch, mats)
        bodies = BodySurface(state.verts.to(self.dtype), state.faces)
        vert_body = torch.tensor(body_ids, dtype=torch.int64)[batch.vert_garment]
        inp = DrapeInput(batch, cloth, torch.cat(x_init), bodies, vert_body)
        t2 = time.perf_counter()
        run = self.model.physics_only if physics_only else self.model
        out = run(inp, steps=steps, keep_trace=keep_trace)
        x = out.x
        t3 = time.perf_counter()
        convergence: list[dict[str, list[float]]] = [{} for _ in jobs]
        if keep_trace:
            states = [out.x_gnn, *out.trace]
            for xt in states:
                e = sum(energy_terms(xt, cloth).values())
                f = (internal_forces(xt, cloth) + out.f_hat).norm(dim=-1)
                fsum = torch.zeros(len(jobs), dtype=f.dtype).index_add_(0, batch.vert_garment, f)
                for k in range(len(jobs)):
                    convergence[k].setdefault("energy", []).append(float(e[k]))
                    convergence[k].setdefault("force", []).append(float(fsum[k]))
        t3b = time.perf_counter()
        if refine:
            from physdrape.physics import relax

            c64 = Cloth.build(batch.to(torch.float64), mats)
            b64 = BodySurface(state.verts.to(torch.float64), state.faces)
            res = relax(x.to(torch.float64), c64, b64, torch.tensor(body_ids), max_iters=refine_iters,
                        time_budget_s=refine_time_s)
            x = res.x.to(self.dtype)
        t4 = time.perf_counter()
        metrics = drape_metrics(x, batch, bodies, vert_body, cloth=cloth).as_dict()
        weight = cloth.mass * cloth.gravity[cloth.vert_garment].norm(dim=-1)
        residual = (internal_forces(x, cloth).norm(dim=-1) / weight).cpu().numpy()
        centroid = x[batch.faces].mean(dim=1)
        inside = bodies.query(centroid, body_index=vert_body[batch.faces[:, 0]]).inside.cpu().numpy()
        t5 = time.perf_counter()
        timings = {"body_s": t1 - t0, "init_s": t2 - t1, "model_s": t3 - t2, "trace_s": t3b - t3, "refine_s": t4 - t3b,
                   "metrics_s": t5 - t4, "total_s": t5 - t0, "batch_size": float(len(jobs))}
        timings["per_garment_s"] = timings["total_s"] / len(jobs)
        xs, inits = batch.split(x), batch.split(inp.x_init)
        res_split = np.split(residual, np.cumsum([g.num_verts for g in garments])[:-1])
        face_split = np.split(inside, np.cumsum([g.num_faces for g in garments])[:-1])
        body_faces = state.faces.cpu().numpy().astype(np.int64)
        results = []
        for k, (template, bp, mat) in enumerate(jobs):
            results.append(DrapeResult(
                name=template.name,
                verts=xs[k].cpu().numpy(),
                faces=template.faces,
                body_verts=state.verts[body_ids[k]].to(self.dtype).cpu().numpy(),
                body_faces=body_faces,
                x_init=inits[k].cpu().numpy(),
                material=mat,
                pose=bp.label,
                metrics={name: float(values[k]) for name, values in metrics.items()},
                timings=dict(timings),
                vertex_residual=res_split[k],
                inside_faces=face_split[k].astype(bool),
                convergence=convergence[k],
                init="warm" if warm is not None and warm[k] is not None else "skinning",
            ))
        return results, affines


def load_smpl_body(path: str | Path, *, gender: str = "neutral", num_betas: int = 10):
    """An `SMPLBody` from a user's model file (.npz / .pkl) or folder; DrapeError naming the fix."""
    p = Path(path).expanduser()
    if not p.exists():
        raise DrapeError(
            f"SMPL model file not found: {p}. SMPL/SMPL-X models are not shipped with PhysDrape: download them "
            "from https://smpl.is.tue.mpg.de (or smpl-x.is.tue.mpg.de) and pass the .npz/.pkl file (or the "
            "folder holding SMPL_NEUTRAL.npz)")
    if p.is_file() and p.suffix.lower() not in (".npz", ".pkl"):
        raise DrapeError(f"SMPL model {p.name}: unknown file type {p.suffix!r}; give the model's .npz (or "
                         "legacy .pkl)")
    from physdrape.body.smpl_body import SMPLBody

    try:
        return SMPLBody(p, gender=gender, num_betas=num_betas)
    except ImportError as exc:
        raise DrapeError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - smplx / numpy / pickle raise many types on bad files
        raise DrapeError(f"cannot load the SMPL model {p}: {exc}") from None


_DEFAULT_DRAPER: Draper | None = None


def drape(garments="default", **kwargs) -> list[DrapeResult]:
    """`Draper().drape(...)` with a Draper (the bundled model) created on first use and reused."""
    global _DEFAULT_DRAPER
    if _DEFAULT_DRAPER is None:
        _DEFAULT_DRAPER = Draper()
    return _DEFAULT_DRAPER.drape(garments, **kwargs)


# ----------------------------------------------------------------------------------------------
# Fitting a garment authored for another body onto the canonical body


@dataclass
class FitResult:
    """A garment placed on the canonical body: verts [m] (V, 3), faces (F, 3), the alignment
    (uniform scale, translation [m]), relaxation stats, and the validation report (text, ok)."""

    name: str
    verts: np.ndarray
    faces: np.ndarray
    scale: float
    translation: list[float]
    relax: dict[str, Any]
    validation: str
    ok: bool

    def report(self) -> dict[str, Any]:
        return {"garment": self.name, "num_verts": len(self.verts), "num_faces": len(self.faces),
                "scale": self.scale, "translation_m": self.translation, "relax": self.relax,
                "valid": self.ok, "validation": self.validation}


#: Height of a top's collar (its highest point) above the canonical body's ``neck01`` joint [m]
#: (measured on the bundled T-shirt: 2.1 cm; the generated tops share its neckline construction).
COLLAR_ABOVE_NECK = 0.021


def _align_to_body(verts: np.ndarray, body, *, scale: float = 1.0) -> np.ndarray:
    """Translation t (x → scale·x + t) putting a top on the canonical body.

    Height: the garment's highest point goes `COLLAR_ABOVE_NECK` above the ``neck01`` joint (a
    top hangs from the shoulders). x/z: centred on the body within the garment's height band,
    then refined by a coordinate descent on 20 × (share of sampled vertices inside the body) +
    mean clearance / 5 cm. Finally lifted (≤ 4 cm, 5 mm steps) while more than 0.5 % of the
    sampled vertices are inside. The scale is not searched: "snug without penetrating" prefers
    ever smaller garments (it shrank a T-shirt to 0.75 around the neck in our test).
    """
    from physdrape.geometry.proximity import BodySurface

    shape = body.default_shape(1, dtype=torch.float64)
    canonical = body.rest_verts(shape)[0]
    neck_y = float(body.rest_joints(shape)[0, body.joint_index("neck01"), 1])
    surface = BodySurface(canonical, body.faces)
    bv = canonical.numpy()
    rng = np.random.default_rng(0)
    sample = verts[rng.choice(len(verts), size=min(len(verts), 1000), replace=False)] * scale
    top = float((verts[:, 1] * scale).max())
    y_shift = neck_y + COLLAR_ABOVE_NECK - top
    ys = sample[:, 1] + y_shift
    # torso only: the central 40 % of the garment's width (arms and hands would bias the centre)
    g_mid_x = 0.5 * (sample[:, 0].min() + sample[:, 0].max())
    half = 0.2 * (sample[:, 0].max() - sample[:, 0].min())
    g_core = sample[np.abs(sample[:, 0] - g_mid_x) < half]
    b_band = bv[(bv[:, 1] >= ys.min()) & (bv[:, 1] <= ys.max())]
    b_mid_x = 0.5 * (b_band[:, 0].min() + b_band[:, 0].max())
    b_core = b_band[np.abs(b_band[:, 0] - b_mid_x) < half]
    t = np.array([b_mid_x - g_mid_x, y_shift,
                  0.5 * (b_core[:, 2].min() + b_core[:, 2].max()) - 0.5 * (g_core[:, 2].min() + g_core[:, 2].max())])

    def distances(shift: np.ndarray) -> np.ndarray:
        return surface.query(torch.from_numpy(sample + shift)).signed_distance.numpy()

    def score(shift: np.ndarray) -> float:
        d = distances(shift)
        return 20.0 * float((d < 0).mean()) + float(np.clip(d, 0, None).mean()) / 0.05

    value, step = score(t), 0.01
    for _ in range(3):
        for k in (0, 2):
            for sign in (-1.0, 1.0):
                trial = t.copy()
                trial[k] += sign * step
                v = score(trial)
                if v < value:
                    value, t = v, trial
        step /= 2
    for _ in range(8):
        if float((distances(t) < 0).mean()) <= 0.005:
            break
        t = t + np.array([0.0, 0.005, 0.0])
    return t


def fit_garment(path: str | Path, *, align: bool = True, scale: float = 1.0, iters: int = 20,
                time_budget_s: float = 60.0, body=None) -> FitResult:
    """Place a garment authored for another body onto the canonical Anny body.

    An .mhclo is refit through its MakeHuman binding (exact); an .obj/.ply (metres, y-up) is
    scaled by `scale` and translated onto the body (`_align_to_body`), pushed out of the body, then
    relaxed with the physics oracle (`physics.relax`, the garment's own aligned shape as rest
    state, gravity and body contact, at most `iters` Newton iterations) and validated as a
    template (`garments.validate_garment`: no self-intersections, >= 2 mm body clearance).
    Crossing layers (a suit's top over its trousers) and creases are untangled locally
    (`garments.untangle.untangle_garment`) before the relaxation and again after it, which also
    puts the sheet back at the margin; if the relaxed shape cannot be untangled (the physics has
    no self-collision) the untangled rest shape is returned (``relax["discarded"]`` says so).
    ``relax`` also holds the untangling stats and, for an .mhclo, the displacement from the raw
    MakeHuman refit.

    Raises:
        DrapeError / MeshError: unreadable file, wrong unit, or a malformed mesh.
    """
    from physdrape.garments import load_mhclo, validate_garment
    from physdrape.garments.mhclo import resolve_body_penetration
    from physdrape.garments.untangle import untangle_garment
    from physdrape.geometry.garment import Garment
    from physdrape.geometry.mesh import check_mesh, read_mesh
    from physdrape.geometry.proximity import BodySurface
    from physdrape.physics import Cloth, relax

    path = Path(path).expanduser()
    if not path.is_file():
        raise DrapeError(f"garment file not found: {path}")
    if body is None:
        from physdrape.body.anny_body import get_anny_body

        body = get_anny_body()
    canonical = body.canonical_verts(dtype=torch.float64)
    faces_b = body.faces
    if not 0.2 <= scale <= 5.0:
        raise DrapeError(f"scale {scale:g} is implausible for a garment in metres: give a factor near 1 "
                         "(convert units first: 0.01 for cm, 0.1 for dm)")
    shift = np.zeros(3)
    bv, bf = canonical.numpy(), faces_b.numpy()
    raw = None
    if path.suffix.lower() == ".mhclo":
        g = load_mhclo(path, resolve_margin=None)
        raw = np.asarray(g.verts, np.float64)
        verts, faces, name = raw.copy(), np.asarray(g.faces, np.int64), g.name
        verts, _ = resolve_body_penetration(verts, faces, bv, bf, margin=2e-3)
    else:
        verts, faces = read_mesh(path)
        name = path.stem
        check_mesh(verts, faces, name=path.name)
        extent = float(np.ptp(verts, axis=0).max())
        if extent > 3.0:
            raise DrapeError(f"{path.name} is {extent:.3g} units across: PhysDrape needs metres "
                             "(scale it by 0.01 for cm, 0.1 for dm, 0.001 for mm)")
        pre = validate_garment(verts, faces, name=path.name, body=False, check_self_intersections=False,
                               require_clearance=False)
        topo = [e for e in pre.errors if "non-manifold" in e or "more than two faces" in e]
        if topo:
            raise DrapeError(f"{path.name}: {topo[0]}; repair the mesh (e.g. split non-manifold edges) and retry")
        faces = faces.astype(np.int64)
        if align:
            shift = _align_to_body(verts, body, scale=scale)
        verts = verts * scale + shift
        verts, _ = resolve_body_penetration(verts, faces, bv, bf, margin=2e-3)
    # Layered pieces (a suit's top over its trousers) and tight creases cross each other once
    # refit/pushed out: untangle them locally before the physics takes this shape as its rest state.
    verts, info = untangle_garment(verts, faces, bv, bf, margin=2e-3)
    untangle_stats = {"before_relax": info.as_dict()}
    rest = verts
    stats: dict[str, Any] = {"iterations": 0}
    if iters > 0:
        garment = Garment.from_mesh(verts, faces, name=name, dtype=torch.float64)
        cloth = Cloth.build(garment)
        result = relax(torch.from_numpy(verts), cloth, BodySurface(canonical, faces_b), max_iters=iters,
                       time_budget_s=time_budget_s)
        verts = result.x.numpy()
        stats = {"iterations": len(result.history) - 1, "reason": result.reason, "wall_time_s": result.wall_time,
                 "residual": float(result.residual[0]),
                 "energy_J": {k: float(v[0]) for k, v in result.energy_terms.items()}}
    if iters > 0:  # the relaxed sheet rests in contact: back out to the margin, untangle again
        relaxed, info = untangle_garment(verts, faces, bv, bf, margin=2e-3)
        untangle_stats["after_relax"] = info.as_dict()
        if info.faces_after and not untangle_stats["before_relax"]["self_intersecting_faces_after"]:
            # the physics has no self-collision: layers it pushed through each other that the
            # local untangling cannot separate again -> keep the valid unrelaxed shape
            stats["discarded"] = (f"the relaxed shape kept {info.faces_after} self-intersecting faces; "
                                  "the aligned, untangled shape (the physics rest state) is returned")
            verts = rest
        else:
            verts = relaxed
    stats["untangle"] = untangle_stats
    if raw is not None:  # how far the fit moved the MakeHuman refit [m]
        disp = np.linalg.norm(verts - raw, axis=1)
        stats["displacement_from_refit_m"] = {"max": float(disp.max()), "mean": float(disp.mean())}
    report = validate_garment(verts, faces, name=name, body=(bv, bf), margin=2e-3, require_clearance=True)
    return FitResult(name=name, verts=verts, faces=faces, scale=float(scale), translation=[float(v) for v in shift],
                     relax=stats, validation=str(report), ok=report.ok)
