"""Manifests of drape jobs: a JSON-lines file, one job per line, read and checked line by line.

A job is a JSON object with the keys below, each optional; their spellings are those of
`Draper.drape` and of `physdrape drape` (docs/manifest.md has an example)::

    {"id": "a1", "garment": "tshirt:7", "shape": {"weight": 0.8}, "pose": "stand", "material": "denim"}

- ``id``: the job's output folder name (letters, digits, ``.``, ``_``, ``-``; at most 100
  characters, not starting with ``.`` or ``summary.``); default ``line-NNNNNN``, its line number.
- ``garment``: "default", CATEGORY:SEED (e.g. "tshirt:7") or an .obj/.ply/.mhclo file.
- ``shape``: Anny phenotypes {name: value in [0, 1]} or 6 values; on SMPL, β (a list).
- ``pose``: a preset name, "random:SEED", {"bvh": FILE, "frame": N}, axis-angles (J, 3) as
  nested lists; on SMPL "rest", θ as nested lists or {"amass": FILE, "frame": N}.
- ``material``: a preset name, or {"preset": NAME, "mu": Pa, "lam": Pa, "k_bend": J,
  "density": kg/m²} (every key optional: the preset, cotton by default, with those values replaced).
- ``units``: the unit of an .obj/.ply garment ("m", "dm", "cm", "mm"; default: the run's).

Relative file paths are read from the manifest's folder. Blank lines are skipped; every other
line is one job, numbered from 0 in file order (`ManifestJob.index`), which decides its shard.
These checks are cheap (no mesh is read, no body posed): what only draping can tell (a garment
that does not fit, a pose with the arms through the torso) fails that job, not the manifest.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from physdrape.api.placement import UNITS
from physdrape.api.specs import GARMENT_CATEGORIES, is_generated
from physdrape.api.types import DrapeError, Motion
from physdrape.physics.material import Material
from physdrape.physics.presets import MATERIAL_PRESETS, out_of_range

#: The keys a job may have.
JOB_KEYS = ("id", "garment", "shape", "pose", "material", "units")
#: The keys of a material given as an object: a preset and the constants it replaces (SI units).
MATERIAL_KEYS = ("preset", "mu", "lam", "k_bend", "density")
#: The named poses of an SMPL body (Anny's are `physdrape.body.poses.PRESETS`).
SMPL_POSE_NAMES = ("rest", "t-pose")
_ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,99}$")
_RANDOM_POSE = re.compile(r"^random:\d+$")
#: Output files beside the job folders start with this; no job id may.
RESERVED_PREFIX = "summary."
#: How many bad lines an error message lists before "and N more".
MAX_LISTED = 20


@dataclass(frozen=True, eq=False)
class ManifestJob:
    """One valid line of a manifest, resolved into `Draper.drape` arguments.

    index: the job's number among the manifest's lines (blank lines not counted), from 0; job
        `index` belongs to rank ``index % world_size``.
    line: its line number in the file, from 1. id: its output folder's name.
    spec: the JSON object as written (recorded beside the outputs; a changed line is a new job).
    garment, shape, pose, material, units: the arguments of `Draper.drape` for this job (paths
        made absolute, material resolved). notes: what is draped although likely wrong.
    """

    index: int
    line: int
    id: str
    spec: dict[str, Any]
    garment: str
    shape: dict[str, float] | list[float] | None
    pose: str | Motion | np.ndarray | None
    material: Material
    units: str
    notes: tuple[str, ...] = field(default=())

    @property
    def rig(self) -> str:
        """The body rig the pose drapes on: "cmu_mb" for BVH frames, else "anny" (or SMPL's)."""
        return "cmu_mb" if isinstance(self.pose, Motion) and Path(self.pose.path).suffix.lower() == ".bvh" \
            else "anny"


@dataclass(frozen=True)
class BadLine:
    """A line that is not a valid job: its number among the jobs (`ManifestJob.index`), its line
    number and what is wrong with it."""

    index: int
    line: int
    error: str

    def __str__(self) -> str:
        return f"line {self.line}: {self.error}"


@dataclass(frozen=True)
class Manifest:
    """A read manifest: its valid jobs and its bad lines, both in file order."""

    path: Path
    jobs: tuple[ManifestJob, ...]
    bad: tuple[BadLine, ...]

    def shard(self, rank: int, world_size: int) -> Manifest:
        """The jobs (and bad lines) of `rank` among `world_size` processes: job j is rank j mod world_size's."""
        check_rank(rank, world_size)
        return Manifest(self.path, tuple(j for j in self.jobs if j.index % world_size == rank),
                        tuple(b for b in self.bad if b.index % world_size == rank))


class ManifestError(DrapeError):
    """A manifest with bad lines; `bad` lists them, the message names each (up to `MAX_LISTED`)."""

    def __init__(self, path: Path, bad: tuple[BadLine, ...]) -> None:
        listed = "; ".join(str(b) for b in bad[:MAX_LISTED])
        more = f"; and {len(bad) - MAX_LISTED} more" if len(bad) > MAX_LISTED else ""
        super().__init__(f"manifest {path}: {len(bad)} bad line(s), nothing draped: {listed}{more}. Fix them, or "
                         "skip them and drape the rest (CLI --skip-bad-lines; API skip_bad_lines=True)")
        self.bad = bad


def check_rank(rank: int, world_size: int) -> None:
    """Refuse a rank outside [0, world_size)."""
    if not (isinstance(world_size, int) and world_size >= 1 and isinstance(rank, int) and 0 <= rank < world_size):
        raise DrapeError(f"rank {rank!r} of world size {world_size!r}: need an integer world size >= 1 and "
                         "0 <= rank < world size (torchrun sets RANK and WORLD_SIZE)")


def read_manifest(path: str | Path, *, smpl: bool = False, units: str = "m") -> Manifest:
    """Read and check a JSON-lines manifest (see the module's docstring).

    smpl: the jobs drape on an SMPL body (garments must be .obj/.ply files, poses θ or AMASS
    frames, shapes β). units: the unit of .obj/.ply garments of jobs without "units".

    Returns every valid job and every bad line; nothing is draped or refused here (see
    `ManifestError` for the policy of `run_manifest`). Raises DrapeError only when the file
    itself cannot be read.
    """
    path = Path(path).expanduser()
    if units not in UNITS:
        raise DrapeError(f"units must be one of {', '.join(UNITS)}, got {units!r}")
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise DrapeError(f"manifest {path}: no such file; give a JSON-lines file, one job per line "
                         "(docs/manifest.md)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DrapeError(f"cannot read manifest {path}: {exc}") from None
    base = path.resolve().parent
    jobs: list[ManifestJob] = []
    bad: list[BadLine] = []
    seen: dict[str, int] = {}
    index = 0
    for number, raw in enumerate(text.splitlines(), start=1):
        if not raw.strip():
            continue
        try:
            job = _job(raw, index, number, base, smpl=smpl, units=units)
            if job.id in seen:
                raise DrapeError(f"id {job.id!r} repeats line {seen[job.id]}'s; ids name output folders and "
                                 "must be unique")
            seen[job.id] = number
            jobs.append(job)
        except DrapeError as exc:
            bad.append(BadLine(index, number, str(exc)))
        index += 1
    if not jobs and not bad:
        raise DrapeError(f"manifest {path} holds no jobs; write one JSON object per line (docs/manifest.md)")
    return Manifest(path, tuple(jobs), tuple(bad))


def _job(raw: str, index: int, number: int, base: Path, *, smpl: bool, units: str) -> ManifestJob:
    try:
        spec = json.loads(raw)
    except json.JSONDecodeError as exc:
        raise DrapeError(f"not JSON ({exc.msg} at column {exc.colno}); write one JSON object per line") from None
    if not isinstance(spec, dict):
        raise DrapeError(f"a job is a JSON object {{\"garment\": ..., \"pose\": ...}}, got {type(spec).__name__}")
    unknown = sorted(set(spec) - set(JOB_KEYS))
    if unknown:
        raise DrapeError(f"unknown key(s) {', '.join(map(repr, unknown))}; a job has {', '.join(JOB_KEYS)}")
    checks = {"id": lambda: _id(spec.get("id"), number),
              "garment": lambda: _garment(spec.get("garment", "default"), base, smpl=smpl),
              "shape": lambda: _shape(spec.get("shape"), smpl=smpl),
              "pose": lambda: _pose(spec.get("pose"), base, smpl=smpl),
              "material": lambda: _material(spec.get("material")),
              "units": lambda: _units(spec.get("units", units))}
    values, errors = {}, []
    for key, check in checks.items():  # every field is checked, so that one message names all a line's faults
        try:
            values[key] = check()
        except DrapeError as exc:
            errors.append(str(exc))
    if errors:
        raise DrapeError("; ".join(errors))
    material, notes = values.pop("material")
    return ManifestJob(index=index, line=number, spec=spec, material=material, notes=notes, **values)


def _units(value) -> str:
    if value not in UNITS:
        raise DrapeError(f"units {value!r}: choose one of {', '.join(UNITS)}")
    return value


def _id(value, number: int) -> str:
    if value is None:
        return f"line-{number:06d}"
    if isinstance(value, int) and not isinstance(value, bool):
        value = str(value)
    if not isinstance(value, str) or not _ID.match(value) or value.startswith(RESERVED_PREFIX):
        raise DrapeError(f"id {value!r} is not a folder name: use 1 to 100 letters, digits, '.', '_' or '-', "
                         f"not starting with '.' or {RESERVED_PREFIX!r}")
    return value


def _file(value: str, base: Path, what: str) -> Path:
    path = Path(value).expanduser()
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise DrapeError(f"{what} {value!r}: no such file (relative paths are read from the manifest's folder, "
                         f"{base})")
    return path


def _garment(value, base: Path, *, smpl: bool) -> str:
    if not isinstance(value, str) or not value:
        raise DrapeError(f"garment must be a string: 'default', CATEGORY:SEED or a file, got {value!r}")
    if value == "default" or is_generated(value):
        if smpl:
            raise DrapeError(f"garment {value!r} is made for the Anny body; an SMPL body takes .obj/.ply files "
                             "authored on its canonical body")
        return value
    suffixes = (".obj", ".ply") if smpl else (".obj", ".ply", ".mhclo")
    if Path(value).suffix.lower() not in suffixes:
        raise DrapeError(f"garment {value!r}: not 'default', CATEGORY:SEED (CATEGORY in "
                         f"{', '.join(GARMENT_CATEGORIES)}, e.g. tshirt:7) or a {'/'.join(suffixes)} file")
    return str(_file(value, base, "garment"))


def _number(value, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise DrapeError(f"{what} must be a finite number, got {value!r}")
    return float(value)


def _shape(value, *, smpl: bool):
    from physdrape.body.anny_body import PHENOTYPE_NAMES

    if value is None:
        return None
    if smpl:
        if not isinstance(value, list) or not value:
            raise DrapeError(f"shape on an SMPL body is β, a list of numbers (e.g. [1.2, -0.5]), got {value!r}")
        return [_number(v, "shape β") for v in value]
    if isinstance(value, dict):
        unknown = sorted(set(value) - set(PHENOTYPE_NAMES))
        if unknown:
            raise DrapeError(f"shape: unknown phenotype(s) {', '.join(map(repr, unknown))}; the names are "
                             f"{', '.join(PHENOTYPE_NAMES)}")
        shape = {k: _number(v, f"shape {k}") for k, v in value.items()}
    elif isinstance(value, list) and len(value) == len(PHENOTYPE_NAMES):
        shape = dict(zip(PHENOTYPE_NAMES, (_number(v, "shape value") for v in value)))
    else:
        raise DrapeError(f"shape must be {{name: value}} or {len(PHENOTYPE_NAMES)} values in the order "
                         f"{', '.join(PHENOTYPE_NAMES)}, got {value!r}")
    outside = [f"{k} = {v:g}" for k, v in shape.items() if not 0.0 <= v <= 1.0]
    if outside:
        raise DrapeError(f"shape: {', '.join(outside)} outside [0, 1]; phenotypes are values in [0, 1]")
    return shape if isinstance(value, dict) else [shape[k] for k in PHENOTYPE_NAMES]


def _pose(value, base: Path, *, smpl: bool):
    from physdrape.body.poses import PRESETS

    if value is None:
        return None
    if isinstance(value, str):
        names = SMPL_POSE_NAMES if smpl else PRESETS
        if value in names or (not smpl and _RANDOM_POSE.match(value)):
            return value
        other = "" if smpl else ", random:SEED"
        raise DrapeError(f"unknown pose {value!r}; choose one of {', '.join(names)}{other}, "
                         f"{{\"{'amass' if smpl else 'bvh'}\": FILE, \"frame\": N}} or axis-angles [[x, y, z], ...]")
    if isinstance(value, dict):
        kind = "amass" if smpl else "bvh"
        extra = sorted(set(value) - {kind, "frame"})
        if extra or kind not in value:
            raise DrapeError(f"a pose object is {{\"{kind}\": FILE, \"frame\": N}}"
                             + (f"; unknown key(s) {', '.join(map(repr, extra))}" if extra else ""))
        frame = value.get("frame", 0)
        if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
            raise DrapeError(f"pose frame must be an integer >= 0, got {frame!r}")
        if not isinstance(value[kind], str):
            raise DrapeError(f"pose {kind} must be a file path, got {value[kind]!r}")
        path = _file(value[kind], base, f"pose {kind}")
        if path.suffix.lower() != (".npz" if smpl else ".bvh"):
            raise DrapeError(f"pose {kind} {value[kind]!r} must be a {'.npz' if smpl else '.bvh'} file")
        return Motion(path, frame, warm_start=False)
    if isinstance(value, list):
        try:
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            arr = np.zeros(0)
        if arr.ndim != 2 or arr.shape[1] != 3 or not len(arr) or not np.isfinite(arr).all():
            raise DrapeError("a pose array is axis-angles [rad], one [x, y, z] per joint, finite numbers")
        return arr
    raise DrapeError(f"pose must be a name, a {{\"bvh\": FILE, \"frame\": N}} object or axis-angles, got {value!r}")


def _material(value) -> tuple[Material, tuple[str, ...]]:
    if value is None:
        return MATERIAL_PRESETS["cotton"], ()
    if isinstance(value, str):
        value = {"preset": value}
    if not isinstance(value, dict):
        raise DrapeError(f"material must be a preset name ({', '.join(MATERIAL_PRESETS)}) or an object with "
                         f"{', '.join(MATERIAL_KEYS)}, got {value!r}")
    unknown = sorted(set(value) - set(MATERIAL_KEYS))
    if unknown:
        raise DrapeError(f"material: unknown key(s) {', '.join(map(repr, unknown))}; a material has "
                         f"{', '.join(MATERIAL_KEYS)} (SI units)")
    preset = value.get("preset", "cotton")
    if preset not in MATERIAL_PRESETS:
        raise DrapeError(f"material preset {preset!r}: choose one of {', '.join(MATERIAL_PRESETS)}")
    constants = {k: _number(v, f"material {k}") for k, v in value.items() if k != "preset"}
    for k, v in constants.items():
        if not v > 0:
            raise DrapeError(f"material {k} must be positive (mu, lam in Pa; k_bend in J; density in kg/m^2), "
                             f"got {v:g}")
    material = replace(MATERIAL_PRESETS[preset], **constants)
    notes = tuple(f"{note}; the model was trained only inside these ranges" for note in out_of_range(material))
    return material, notes
