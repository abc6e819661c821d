"""CLOTH3D garments (for users who hold the CLOTH3D licence; nothing of it is shipped).

Layout of a CLOTH3D sample directory (e.g. ``train/01_01_s0/``)::

    info.mat            MATLAB struct: outfit.<Garment>.{fabric, texture, ...}, gender (0 female,
                        1 male), shape (10 SMPL betas), poses, trans, zrot, ...
    <Garment>.obj       the garment in the rest T-pose on that sample's SMPL body (metres,
                        y-up), quads and triangles; ``Top``, ``Tshirt``, ``Trousers``, ``Skirt``,
                        ``Dress``, ``Jumpsuit``
    <Garment>.pc16      the simulated sequence (not read here)

The garments load as templates in their own T-pose frame (SMPL body of the sample, not the
canonical Anny A-pose): use them with the SMPL backend, or transfer them to Anny first.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from physdrape.garments.generator import GarmentTemplate
from physdrape.garments.remesh import remesh
from physdrape.geometry.mesh import MeshError, read_mesh

__all__ = ["read_cloth3d_info", "list_cloth3d_garments", "load_cloth3d_garment", "UPPER_BODY_GARMENTS"]

#: CLOTH3D garment types that cover the upper body (the paper's "tops").
UPPER_BODY_GARMENTS = ("Top", "Tshirt", "Dress", "Jumpsuit")


def _to_python(obj):
    """scipy.io mat_struct / arrays → plain dicts, lists and scalars."""
    from scipy.io.matlab import mat_struct

    if isinstance(obj, mat_struct):
        return {k: _to_python(getattr(obj, k)) for k in obj._fieldnames}
    if isinstance(obj, dict):
        return {k: _to_python(v) for k, v in obj.items() if not k.startswith("__")}
    if isinstance(obj, np.ndarray):
        if obj.dtype == object:
            return [_to_python(o) for o in obj.ravel()]
        return obj
    return obj


def read_cloth3d_info(sample_dir: str | os.PathLike) -> dict:
    """The sample's ``info.mat`` as a plain dict (``outfit`` maps garment name → properties)."""
    import scipy.io

    path = Path(sample_dir) / "info.mat"
    if not path.is_file():
        raise MeshError(f"{path} not found: give a CLOTH3D sample directory (with info.mat and <Garment>.obj)")
    try:
        raw = scipy.io.loadmat(str(path), squeeze_me=True, struct_as_record=False)
    except Exception as err:  # scipy raises several types on bad files
        raise MeshError(f"could not read {path} as a MATLAB file: {err}") from err
    info = _to_python(raw)
    if "outfit" not in info or not isinstance(info["outfit"], dict):
        raise MeshError(f"{path} has no 'outfit' struct: not a CLOTH3D info file")
    return info


def list_cloth3d_garments(sample_dir: str | os.PathLike, *, upper_body_only: bool = False) -> list[str]:
    """Garment names of a CLOTH3D sample (sorted), optionally only tops/dresses/jumpsuits."""
    names = sorted(read_cloth3d_info(sample_dir)["outfit"])
    if upper_body_only:
        names = [n for n in names if n in UPPER_BODY_GARMENTS]
    return names


def load_cloth3d_garment(
    sample_dir: str | os.PathLike, garment: str | None = None, *, target_edge: float | None = None
) -> GarmentTemplate:
    """Load one rest-pose (T-pose) garment of a CLOTH3D sample.

    Args:
        sample_dir: the sample directory.
        garment: garment name (``Top``, ``Tshirt``, ...); None = the sample's only upper-body
            garment (error when there are several or none).
        target_edge: remesh to this edge length [m] (None keeps the mesh).

    Returns:
        the garment; ``meta`` holds ``fabric``, ``gender``, ``shape`` and ``sample``.
    """
    sample_dir = Path(sample_dir)
    info = read_cloth3d_info(sample_dir)
    outfit = info["outfit"]
    if garment is None:
        tops = [n for n in sorted(outfit) if n in UPPER_BODY_GARMENTS]
        if len(tops) != 1:
            raise MeshError(
                f"{sample_dir}: {len(tops)} upper-body garments ({', '.join(sorted(outfit))}); pass garment=<name>"
            )
        garment = tops[0]
    if garment not in outfit:
        raise MeshError(f"{sample_dir}: no garment {garment!r} in info.mat (has {', '.join(sorted(outfit))})")
    verts, faces = read_mesh(sample_dir / f"{garment}.obj")
    props = outfit[garment] if isinstance(outfit[garment], dict) else {}
    meta = dict(
        sample=sample_dir.name,
        garment=garment,
        fabric=str(props.get("fabric", "")),
        gender=int(np.asarray(info.get("gender", -1)).ravel()[0]) if "gender" in info else None,
        shape=np.asarray(info.get("shape", np.zeros(10)), np.float64).ravel(),
        frame="CLOTH3D T-pose (SMPL body of the sample)",
    )
    g = GarmentTemplate(verts=verts, faces=faces, name=f"{sample_dir.name}_{garment}", meta=meta)
    if target_edge is not None:
        g.verts, g.faces = remesh(verts, faces, target_edge=target_edge)
    return g
