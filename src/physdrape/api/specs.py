"""Input specs of the API: what users write for a garment, a body shape, a pose and a material,
turned into templates, shape tensors, body poses and `Material`s, with errors that say what to
write instead. Nothing here drapes; `physdrape.api.draper.Draper` calls these."""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from physdrape.api.placement import check_extent, unit_scale
from physdrape.api.types import DrapeError, Motion
from physdrape.garments.catalogue import CATEGORIES
from physdrape.garments.generated_cache import generated_garment
from physdrape.geometry.mesh import MeshError, check_mesh
from physdrape.physics.material import Material
from physdrape.physics.presets import MATERIAL_PRESETS, material_preset
from physdrape.pipeline import POSE_DTYPE, Template

#: The procedural garments' names (tops, trousers and shorts, outfits: `garments.catalogue`),
#: usable as "category:seed" garment specs.
GARMENT_CATEGORIES = CATEGORIES
_GENERATED = re.compile(rf"^({'|'.join(GARMENT_CATEGORIES)}):(\d+)$")
_RANDOM_POSE = re.compile(r"^random:(\d+)$")
#: The pose used when none is given: a natural standing pose with the arms off the torso.
DEFAULT_POSE = "relaxed"


@dataclass(frozen=True)
class BodyPose:
    """One pose to drape on: `pose` (1, J, 3) axis-angles [rad] on body rig `rig`, a label, and the
    pose's own body shape (1, S) (AMASS betas) or None for the call's shape. `sequence` tags the
    frames of a warm-started motion: (sequence id, frame number, warm mode). `clear_arms`: turn
    the arms out where they press against the torso (`Motion.clear_arms`)."""

    rig: str
    pose: Tensor
    label: str
    shape: Tensor | None = None
    sequence: tuple[int, int, str] | None = None
    clear_arms: bool = False


def is_generated(text: str) -> bool:
    """Whether `text` names a generated garment, CATEGORY:SEED."""
    return bool(_GENERATED.match(text))


def template_from_mesh(name: str, verts, faces, *, units: str = "m") -> Template:
    """A template from a user's mesh in `units` (converted to metres), refused (MeshError /
    DrapeError) when malformed or when its size says it is in another unit."""
    scale = unit_scale(units)
    v = np.asarray(verts.detach().cpu() if isinstance(verts, Tensor) else verts, dtype=np.float64) * scale
    f = np.asarray(faces.detach().cpu() if isinstance(faces, Tensor) else faces)
    if v.ndim == 2 and v.shape[1] == 3 and np.isfinite(v).all():
        indices_ok = (f.ndim == 2 and f.size and np.issubdtype(f.dtype, np.integer) and f.min() >= 0
                      and f.max() < len(v))
        check_extent(name, v[np.unique(f)] if indices_ok else v, units)
    check_mesh(v, f, name=name)
    return Template.from_mesh(v, f, name=name)


def garment_template(spec, *, smpl: bool = False, units: str = "m") -> Template:
    """A template from a garment spec: "default", "CATEGORY:SEED", a path (.obj/.ply/.mhclo), a
    (verts (V, 3), faces (F, 3)) pair, or an object with ``.verts``/``.faces``. smpl: the
    Draper drapes on SMPL, where only garment files authored on SMPL's canonical body fit.
    units: the unit of .obj/.ply files and of user meshes ("m", "dm", "cm", "mm"; converted to
    metres); the bundled and generated garments are in metres and an .mhclo is placed through its
    binding to the body, so neither is scaled."""
    unit_scale(units)
    if isinstance(spec, (str, Path)):
        return _template_from_text(str(spec), smpl=smpl, units=units)
    if isinstance(spec, Template):
        return spec
    if isinstance(spec, tuple) and len(spec) == 2:
        return template_from_mesh("garment", *spec, units=units)
    if hasattr(spec, "verts") and hasattr(spec, "faces"):
        return template_from_mesh(str(getattr(spec, "name", "garment")), spec.verts, spec.faces, units=units)
    raise DrapeError(f"cannot interpret garment {type(spec).__name__}: give a path, 'default', CATEGORY:SEED, "
                     "a (verts, faces) pair or an object with .verts and .faces")


def _template_from_text(text: str, *, smpl: bool, units: str) -> Template:
    if smpl and (text == "default" or _GENERATED.match(text) or text.lower().endswith(".mhclo")):
        raise DrapeError(
            f"garment {text!r} is made for the Anny body and does not fit SMPL: with an SMPL body, give a "
            "garment file (.obj/.ply, metres, y-up) authored on SMPL's canonical body (β = 0, zero pose "
            "= T-pose); the bundled default, the generated CATEGORY:SEED garments and .mhclo are Anny-only")
    try:
        if text == "default":
            from physdrape.garments import default_garment

            return template_from_mesh("tshirt_default", *_mesh(default_garment()))
        if _GENERATED.match(text):
            category, seed = text.split(":")
            return template_from_mesh(*generated_garment(category, int(seed)))
        path = Path(text).expanduser()
        if not path.is_file():
            raise DrapeError(f"garment {text!r}: no such file, and not 'default' or CATEGORY:SEED with CATEGORY in "
                             f"{', '.join(GARMENT_CATEGORIES)} (e.g. tshirt:7); give an .obj/.ply in metres on the "
                             "canonical body, or a .mhclo")
        suffix = path.suffix.lower()
        if suffix == ".mhclo":
            from physdrape.garments import load_mhclo
            from physdrape.garments.sizing import MhcloSizer

            g = load_mhclo(path, untangle=True)  # its pieces refit crossing each other: separated
            t = template_from_mesh(g.name, *_mesh(g))
            return replace(t, sizer=MhcloSizer.for_file(path, t.verts, t.faces))
        elif suffix in (".obj", ".ply"):
            return _template_from_file(path, units)
        else:
            raise DrapeError(f"garment file {path} has an unsupported extension {suffix!r}: use .obj, .ply "
                             "(metres, y-up, on the canonical body) or .mhclo")
        return template_from_mesh(g.name, *_mesh(g))
    except (MeshError, DrapeError):
        raise
    except (OSError, ValueError) as exc:
        raise DrapeError(f"cannot load garment {text!r}: {exc}") from None


def _template_from_file(path: Path, units: str) -> Template:
    """An .obj/.ply template read in `units`, converted to metres and validated as
    `garments.load_template` does (topology, triangles, self-intersections, at most 5 % of its
    area inside the canonical body)."""
    from physdrape.garments import validate_garment
    from physdrape.geometry.mesh import read_mesh

    verts, faces = read_mesh(path)
    template = template_from_mesh(path.stem, verts, faces, units=units)
    validate_garment(template.verts, template.faces, name=path.name, require_clearance=False,
                     max_inside_area_fraction=0.05).raise_if_failed()
    return template


def _mesh(garment) -> tuple[np.ndarray, np.ndarray]:
    return garment.verts, garment.faces


def anny_shape(spec, body) -> Tensor:
    """Anny phenotypes (1, 6) from None (canonical), a {name: value} dict or an array of 6."""
    from physdrape.body.anny_body import PHENOTYPE_NAMES, check_phenotypes

    try:
        if spec is None:
            return body.default_shape(1, dtype=POSE_DTYPE)
        if isinstance(spec, dict):
            return body.shape_from_dict(spec, dtype=POSE_DTYPE)
        t = torch.as_tensor(np.asarray(spec, dtype=np.float64)).reshape(-1)
        if t.numel() != len(PHENOTYPE_NAMES):
            raise DrapeError(f"shape must have {len(PHENOTYPE_NAMES)} phenotypes {PHENOTYPE_NAMES}, got {t.numel()}")
        check_phenotypes(t[None])
        return t[None]
    except DrapeError:
        raise
    except (ValueError, TypeError) as exc:
        raise DrapeError(f"bad shape: {exc}") from None


def smpl_betas(spec, body) -> Tensor:
    """SMPL shape β (1, num_betas) from None (β = 0, the canonical body) or up to num_betas
    values (fewer are padded with zeros)."""
    nb = body.num_betas
    if spec is None:
        return torch.zeros(1, nb, dtype=POSE_DTYPE)
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
    out = torch.zeros(1, nb, dtype=POSE_DTYPE)
    out[0, :arr.size] = torch.from_numpy(arr)
    return out


def _as_array(spec, what: str) -> Tensor:
    try:
        return torch.as_tensor(np.asarray(spec.detach().cpu() if isinstance(spec, Tensor) else spec,
                                          dtype=np.float64))
    except (TypeError, ValueError) as exc:
        raise DrapeError(f"bad {what}: {exc}") from None


def anny_poses(spec, body_of: Callable[[str], object]) -> list[BodyPose]:
    """Poses on Anny from None (the default preset), a preset name, "random:SEED" or an array
    (J, 3) / (N, J, 3) of axis-angles [rad] on the "anny" rig. `body_of(rig)` gives the body."""
    from physdrape.body.poses import PRESETS, preset_pose, sample_poses

    spec = DEFAULT_POSE if spec is None else spec
    if isinstance(spec, str):
        m = _RANDOM_POSE.match(spec)
        if m:
            return [BodyPose("anny", sample_poses(body_of("anny"), 1, seed=int(m.group(1)), dtype=POSE_DTYPE), spec)]
        if spec not in PRESETS:
            raise DrapeError(f"unknown pose {spec!r}; choose one of {', '.join(PRESETS)}, random:SEED, or a BVH file")
        return [BodyPose("anny", preset_pose(body_of("anny"), spec, dtype=POSE_DTYPE), spec)]
    body = body_of("anny")
    arr = _as_array(spec, "pose array")
    if arr.dim() == 2:
        arr = arr[None]
    if arr.dim() != 3 or arr.shape[1:] != (body.num_joints, 3):
        raise DrapeError(f"pose arrays must be axis-angles of shape ({body.num_joints}, 3) or "
                         f"(N, {body.num_joints}, 3) for the 'anny' rig, got {tuple(arr.shape)}")
    if not torch.isfinite(arr).all():
        raise DrapeError("pose array contains NaN/inf")
    return [BodyPose("anny", arr[i:i + 1], f"pose[{i}]") for i in range(arr.shape[0])]


def smpl_poses(spec, body) -> list[BodyPose]:
    """Poses on SMPL from None / "rest" (zero θ, the T-pose) or θ as (J, 3), (3J,), (N, J, 3) or
    (N, 3J) axis-angles [rad]."""
    J = body.num_joints
    if spec is None or (isinstance(spec, str) and spec in ("rest", "t-pose")):
        return [BodyPose("smpl", body.rest_pose(1, dtype=POSE_DTYPE), "rest")]
    if isinstance(spec, str):
        raise DrapeError(f"pose {spec!r}: the named presets and random:SEED are defined for Anny; on an SMPL "
                         f"body give θ, axis-angles [rad] of shape ({J}, 3) or ({3 * J},) (or N of them), "
                         "'rest', or AMASS frames Motion('seq.npz', frames=...)")
    arr = _as_array(spec, "SMPL pose θ")
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
    return [BodyPose("smpl", arr[i:i + 1], f"theta[{i}]") for i in range(arr.shape[0])]


def frame_range(motion: Motion, n: int, name: str) -> tuple[int, int]:
    """The motion's frames as a half-open (start, stop) within a file of `n` frames."""
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


def motion_poses(motion: Motion, body_of: Callable[[str], object], *, smpl: bool) -> list[BodyPose]:
    """The frames of a motion: BVH frames retargeted onto Anny's ``cmu_mb`` rig, or (smpl) AMASS
    frames with their betas."""
    path = Path(motion.path).expanduser()
    suffix = path.suffix.lower()
    if smpl:
        if suffix != ".npz":
            raise DrapeError(f"motion {path.name}: an SMPL body takes AMASS .npz frames (poses, betas); BVH "
                             "files are retargeted onto Anny only (use a Draper without smpl_model)")
        if not path.is_file():
            raise DrapeError(f"AMASS file not found: {path}")
        return _amass_poses(motion, path, body_of("smpl"))
    if suffix == ".npz":
        raise DrapeError(f"motion {path.name}: AMASS .npz frames are SMPL poses; create the Draper with "
                         "smpl_model=PATH (CLI: --smpl-model FILE --amass FILE)")
    if not path.is_file():
        raise DrapeError(f"BVH file not found: {path}")
    from physdrape.body.bvh import load_bvh, retarget_bvh

    try:
        bvh = load_bvh(path)
    except Exception as exc:  # noqa: BLE001 - the parser raises several types on malformed files
        raise DrapeError(f"cannot read BVH {path}: {exc}") from None
    start, stop = frame_range(motion, bvh.num_frames, path.name)
    try:
        ret = retarget_bvh(bvh, body_of("cmu_mb"), frames=slice(start, stop))
    except ValueError as exc:
        raise DrapeError(f"cannot retarget {path.name} onto Anny: {exc}") from None
    return [BodyPose("cmu_mb", ret.pose[i:i + 1].to(POSE_DTYPE), f"{path.name}#{start + i}",
                     clear_arms=motion.clear_arms) for i in range(ret.pose.shape[0])]


def _amass_poses(motion: Motion, path: Path, body) -> list[BodyPose]:
    from physdrape.body.poses import load_amass_npz

    try:
        seq = load_amass_npz(path, num_joints=body.num_joints, num_betas=body.num_betas, dtype=POSE_DTYPE)
    except (ValueError, OSError, EOFError) as exc:  # np.load raises several types on bad files
        raise DrapeError(f"cannot read AMASS file {path}: {exc}") from None
    pose, betas = seq["pose"], seq["betas"]
    if pose.shape[0] == 0:
        raise DrapeError(f"AMASS file {path.name} has no frames (poses is empty)")
    start, stop = frame_range(motion, pose.shape[0], path.name)
    pose = pose[start:stop]
    if not torch.isfinite(pose).all():
        bad = int((~torch.isfinite(pose)).flatten(1).any(1).nonzero()[0, 0]) + start
        raise DrapeError(f"AMASS file {path.name}: poses of frame {bad} contain NaN/inf; choose other frames")
    if not torch.isfinite(betas).all():
        raise DrapeError(f"AMASS file {path.name}: betas contain NaN/inf; fix the file or pass shape=β")
    shape = betas.reshape(1, -1)
    return [BodyPose("smpl", pose[i:i + 1], f"{path.name}#{start + i}", shape, clear_arms=motion.clear_arms)
            for i in range(stop - start)]


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
