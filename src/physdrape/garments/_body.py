"""Private access to the canonical body for garment authoring and checks.

The body is `physdrape.body.anny_body.AnnyBody` (closed skin, all phenotypes 0.5, rest A-pose,
y-up metres facing +z). What the generator needs of it - surface, joint heads by name,
dominant bone per vertex, hm08 positions for `.mhclo` refits - is cached to
``~/.cache/physdrape/canonical_body_<key>.npz`` (key: Anny version + digest of the body
module), so tests and split workers load it in milliseconds.
"""

from __future__ import annotations

import functools
import importlib.metadata
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["CanonicalBody", "canonical_body", "hm08_verts"]


def _anny_version() -> str:
    try:
        return importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError:  # pragma: no cover
        return "unknown"


def _cache_dir() -> Path:
    return Path(os.path.expanduser("~")) / ".cache" / "physdrape"


@dataclass(frozen=True)
class CanonicalBody:
    """The canonical body surface and what the garment generator needs of its rig.

    Attributes:
        verts: vertex positions [m], shape (Vb, 3) float64, y-up, facing +z.
        faces: triangles, shape (Fb, 3) int64.
        joints: joint (bone head) positions [m] by bone label, each shape (3,).
        vertex_bone: dominant bone label index per vertex, shape (Vb,) int64 into bone_labels.
        bone_labels: bone names of the Anny rig.
        hm08_verts: the same body on the MakeHuman hm08 topology [m], shape (19158, 3).
    """

    verts: np.ndarray
    faces: np.ndarray
    joints: dict
    vertex_bone: np.ndarray
    bone_labels: tuple
    hm08_verts: np.ndarray


def _build_with_anny() -> dict:
    """The canonical body from `physdrape.body.anny_body.AnnyBody` (the pipeline's body)."""
    import torch

    from physdrape.body.anny_body import get_anny_body

    ab = get_anny_body("anny")
    with torch.no_grad():
        shape = ab.default_shape(1, dtype=torch.float64)
        return dict(
            verts=ab.canonical_verts(dtype=torch.float64).numpy().copy(),
            faces=ab.faces.numpy().astype(np.int64),
            joint_pos=ab.rest_joints(shape)[0].numpy().copy(),
            bone_labels=np.array(ab.joint_names),
            vertex_bone=ab.vertex_part().numpy().astype(np.int64),
            hm08_verts=ab.hm08_verts(shape)[0].numpy().copy(),
        )


def _cache_key() -> str:
    """Anny's version plus a digest of the body module (a changed body invalidates the cache)."""
    import hashlib

    import physdrape.body.anny_body as mod

    digest = hashlib.sha256(Path(mod.__file__).read_bytes()).hexdigest()[:12]
    return f"anny-{_anny_version()}-annybody-{digest}"


@functools.lru_cache(maxsize=1)
def canonical_body() -> CanonicalBody:
    """The canonical body (Anny, phenotypes 0.5, rest pose), y-up metres; cached on disk."""
    path = _cache_dir() / f"canonical_body_{_cache_key()}.npz"
    if not path.exists():
        data = _build_with_anny()
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
        np.savez(tmp, **data)
        os.replace(tmp, path)
    with np.load(path) as z:
        labels = tuple(str(s) for s in z["bone_labels"])
        return CanonicalBody(
            verts=z["verts"].astype(np.float64),
            faces=z["faces"].astype(np.int64),
            joints={lab: z["joint_pos"][i].astype(np.float64) for i, lab in enumerate(labels)},
            vertex_bone=z["vertex_bone"].astype(np.int64),
            bone_labels=labels,
            hm08_verts=z["hm08_verts"].astype(np.float64),
        )


def hm08_verts(phenotype: dict | None = None) -> np.ndarray:
    """Body vertex positions on the MakeHuman hm08 topology for a phenotype [m], (19158, 3).

    Args:
        phenotype: Anny phenotype values by name (``gender``, ``age``, ``muscle``, ``weight``,
            ``height``, ``proportions``, ...), each in [0, 1]; missing ones are 0.5. ``None``
            gives the canonical body (read from the disk cache).
    """
    if not phenotype:
        return canonical_body().hm08_verts
    import torch

    from physdrape.body.anny_body import get_anny_body

    ab = get_anny_body("anny")
    with torch.no_grad():
        shape = ab.shape_from_dict({k: float(v) for k, v in phenotype.items()}, dtype=torch.float64)
        return ab.hm08_verts(shape)[0].numpy().copy()


@functools.lru_cache(maxsize=1)
def _anny_to_hm08_index() -> np.ndarray:
    """hm08 vertex index of every canonical-body vertex, shape (Vb,) (exact position match)."""
    from scipy.spatial import cKDTree

    b = canonical_body()
    dist, idx = cKDTree(b.hm08_verts).query(b.verts)
    if dist.max() > 1e-6:  # pragma: no cover - would mean Anny changed its topologies
        raise RuntimeError("Anny's 'anny' and 'makehuman' topologies no longer share vertices")
    return idx


def body_surface_from_hm08(hm08: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closed body surface (canonical topology) of a body given on hm08 [m]: (verts, faces)."""
    return np.asarray(hm08, np.float64)[_anny_to_hm08_index()], canonical_body().faces
