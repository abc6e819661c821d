"""What PhysDrape reads from the Anny body model (PyPI `anny`), and its copy on disk.

Anny builds a (rig, topology) from its data the first time (minutes; Anny caches the result in
``~/.cache/anny`` or ``$ANNY_CACHE_DIR``), and importing Anny imports torch's compiler stack
(through its dependency `roma`), about a second in every process. What a PhysDrape forward pass
needs is a few tensors: the template and its phenotype blendshapes, the bones, the skinning weights
and how the phenotypes weigh the blendshapes. `load_anny_data` keeps them per (rig, topology,
surface) under ``~/.cache/physdrape/anny_body/anny-<version>/`` (a safetensors file and a JSON file
beside it, written atomically), made from Anny itself the first time and read from there without
importing Anny afterwards.

`phenotype_coefficients` weighs the blendshapes by Anny's rule: each phenotype's value, clamped to
the range of its anchors, is split linearly between the two anchors around it (the weights of its
variations: "minweight", "averageweight", "maxweight", ...); the three race variations share 1/3
each (PhysDrape fixes them, like the phenotypes it does not expose, at 0.5); a blendshape's
coefficient is the product of the weights of the variations its mask row combines. The result is
Anny's to the bit (tests/body/test_anny_data.py).
"""

from __future__ import annotations

import functools
import importlib.metadata
import json
import threading
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from physdrape.atomic import atomic_path, write_text
from physdrape.progress import directory_size, slow_phase
from physdrape.user_cache import cache_root

__all__ = ["ANNY_TO_YUP", "RIGS", "AnnyData", "cache_dir", "load_anny_data", "phenotype_coefficients"]

ANNY_TO_YUP = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64)
"""p_physdrape = ANNY_TO_YUP @ p_anny (a rotation, det +1)."""

RIGS = ("anny", "cmu_mb")

#: Part of the cached files' names: changed whenever what they hold changes.
CACHE_FORMAT = 1

_TENSORS = ("template", "blend", "heads", "heads_blend", "tails", "tails_blend", "mask", "projection", "weights",
            "faces", "vertex_ids", "hm08_ids")


@dataclass(frozen=True)
class AnnyData:
    """Everything a forward pass needs, float64, PhysDrape frame, restricted to `vertex_ids`."""

    template: Tensor  # (V, 3)
    blend: Tensor  # (K, V*3)
    heads: Tensor  # (J, 3)
    heads_blend: Tensor  # (K, J*3)
    tails: Tensor | None  # (J, 3)
    tails_blend: Tensor | None  # (K, J*3)
    mask: Tensor  # (K', C) which of the C phenotype variations each blendshape combines
    projection: Tensor | None  # (K', K)
    weights: Tensor  # dense skinning weights (V, J)
    faces: Tensor  # (F, 3) int64, into the V kept vertices
    vertex_ids: Tensor  # (V,) index of each kept vertex in Anny's mesh
    hm08_ids: Tensor  # (V,) index of each kept vertex in the hm08 base mesh
    phenotype_labels: tuple[str, ...]
    bone_labels: tuple[str, ...]
    parents: tuple[int, ...]
    variations: tuple[tuple[str, int], ...]  # per phenotype, in the mask's column order: (name, variations)
    anchors: dict  # per interpolated phenotype: (first anchor, last anchor) of its evenly spaced anchors


def _anny_version() -> str:
    try:
        return importlib.metadata.version("anny")
    except importlib.metadata.PackageNotFoundError as e:  # pragma: no cover - anny is a hard dependency
        raise ImportError("the Anny body needs the `anny` package: pip install anny") from e


def cache_dir() -> Path:
    """Where `load_anny_data` keeps its files: ~/.cache/physdrape/anny_body/anny-<installed version>."""
    return cache_root() / "anny_body" / f"anny-{_anny_version()}"


_LOCK = threading.Lock()


@functools.lru_cache(maxsize=None)
def load_anny_data(rig: str, topology: str, surface_only: bool) -> AnnyData:
    """The data of Anny's `rig` on `topology` ("anny" or "makehuman"; surface_only: the largest
    connected component, the closed skin), from the cache, or made from Anny and cached."""
    if rig not in RIGS:
        raise ValueError(f"unknown Anny rig {rig!r}; expected one of {RIGS}")
    stem = cache_dir() / f"{rig}_{topology}_{'surface' if surface_only else 'all'}_v{CACHE_FORMAT}"
    with _LOCK:
        data = _read(stem)
        if data is None:
            data = _from_anny(rig, topology, surface_only)
            try:
                _write(stem, data)
            except OSError as e:  # a read-only or full disk: drape on, from Anny in every process
                warnings.warn(f"could not keep the Anny body data in {stem.parent} ({e}); every process will read "
                              "it from Anny again, about a second more: make that folder writable to avoid it",
                              stacklevel=2)
    return data


def _read(stem: Path) -> AnnyData | None:
    """The cached data at `stem` (.json and .safetensors), or None where there is none or it
    cannot be read (it is then made again)."""
    meta_path, tensor_path = stem.with_suffix(".json"), stem.with_suffix(".safetensors")
    if not (meta_path.is_file() and tensor_path.is_file()):
        return None
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        meta = json.loads(meta_path.read_text())
        tensors = load_file(str(tensor_path))
        return AnnyData(**{name: tensors.get(name) for name in _TENSORS},
                        phenotype_labels=tuple(meta["phenotype_labels"]), bone_labels=tuple(meta["bone_labels"]),
                        parents=tuple(meta["parents"]),
                        variations=tuple((name, int(n)) for name, n in meta["variations"]),
                        anchors={name: tuple(ends) for name, ends in meta["anchors"].items()})
    except (OSError, ValueError, KeyError, TypeError, SafetensorError):
        return None


def _write(stem: Path, data: AnnyData) -> None:
    """Cache `data` at `stem`: the tensors first, then the JSON that says they are complete."""
    from safetensors.torch import save_file

    tensors = {name: getattr(data, name).contiguous() for name in _TENSORS if getattr(data, name) is not None}
    with atomic_path(stem.with_suffix(".safetensors")) as tmp:
        save_file(tensors, str(tmp))
    meta = {"format": CACHE_FORMAT, "anny": _anny_version(),
            "phenotype_labels": list(data.phenotype_labels), "bone_labels": list(data.bone_labels),
            "parents": list(data.parents), "variations": [list(v) for v in data.variations],
            "anchors": {name: list(ends) for name, ends in data.anchors.items()}}
    write_text(stem.with_suffix(".json"), json.dumps(meta, indent=1) + "\n")


def _largest_component(faces: np.ndarray, num_verts: int) -> np.ndarray:
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    rows = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]])
    cols = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]])
    adj = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_verts, num_verts))
    _, label = connected_components(adj, directed=False)
    used = np.unique(faces)
    best = np.bincount(label[used]).argmax()
    return np.nonzero(label == best)[0]


def _from_anny(rig: str, topology: str, surface_only: bool) -> AnnyData:
    """The data made from Anny itself (built by Anny the first time on this machine)."""
    from physdrape.warp_runtime import warp

    warp()  # Anny uses Warp: start it here, quietly, before Anny does
    try:
        import anny
    except ImportError as e:  # pragma: no cover - anny is a hard dependency
        raise ImportError("the Anny body needs the `anny` package: pip install anny") from e
    from anny.models.model_data import PHENOTYPE_VARIATIONS
    from anny.models.phenotype import make_phenotype_anchors
    from anny.paths import get_anny_cache_path

    cache = get_anny_cache_path()
    with slow_phase(f"building the Anny body model (rig {rig}): once per machine and rig, about a minute; "
                    f"it is cached in {cache}", done=lambda: f"the cache {cache} holds {directory_size(cache)}"):
        m = anny.Anny(rig=rig, topology=topology, local_changes="none", facial_actions="none")
    C = ANNY_TO_YUP
    dt = torch.float64
    template = m.template_vertices.detach().to(dt) @ C.T
    K = m.blendshapes.shape[0]
    blend = m.blendshapes.detach().to(dt) @ C.T  # (K, V, 3)
    faces = m.faces.detach().cpu().long()
    if faces.shape[1] != 3:  # quads (the full makehuman topology): only positions are used
        faces = torch.zeros(0, 3, dtype=torch.long)
    num_verts = template.shape[0]
    if surface_only:
        keep = torch.from_numpy(_largest_component(faces.numpy(), num_verts))
        remap = torch.full((num_verts,), -1, dtype=torch.long)
        remap[keep] = torch.arange(len(keep))
        fk = remap[faces]
        faces = fk[(fk >= 0).all(1)]
    else:
        keep = torch.arange(num_verts)
    J = len(m.bone_labels)
    dense = torch.zeros(num_verts, J, dtype=dt)
    dense.scatter_add_(1, m.vertex_bone_indices.long(), m.vertex_bone_weights.detach().to(dt))
    tails = tails_blend = None
    if getattr(m, "template_bone_tails", None) is not None:
        tails = m.template_bone_tails.detach().to(dt) @ C.T
        tails_blend = (m.bone_tails_blendshapes.detach().to(dt) @ C.T).reshape(K, -1)
    proj = m.phenotype_blendshape_projection
    anchors = make_phenotype_anchors(dt)
    return AnnyData(
        template=template[keep].contiguous(),
        blend=blend[:, keep].reshape(K, -1).contiguous(),
        heads=m.template_bone_heads.detach().to(dt) @ C.T,
        heads_blend=(m.bone_heads_blendshapes.detach().to(dt) @ C.T).reshape(K, -1),
        tails=tails,
        tails_blend=tails_blend,
        mask=m.stacked_phenotype_blend_shapes_mask.detach().clone(),
        projection=None if proj is None else proj.detach().to(dt),
        weights=dense[keep].contiguous(),
        faces=faces.contiguous(),
        vertex_ids=keep,
        hm08_ids=m.base_mesh_vertex_indices.detach().long()[keep],
        phenotype_labels=tuple(m.phenotype_labels),
        bone_labels=tuple(m.bone_labels),
        parents=tuple(int(p) for p in m.bone_parents),
        variations=tuple((name, len(keys)) for name, keys in PHENOTYPE_VARIATIONS.items()),
        anchors={name: (float(a[0]), float(a[-1])) for name, a in anchors.items()},
    )


def _split_weights(value: Tensor, anchors: Tensor) -> Tensor:
    """Each value (B,), clamped to the anchors' range, split linearly between the two anchors
    around it: (B, n) weights summing to 1, at most two of them non-zero."""
    value = torch.where(value < anchors[0], anchors[0], value)
    value = torch.where(value > anchors[-1], anchors[-1], value)
    right = torch.searchsorted(anchors, value.contiguous(), side="left").clamp(1, len(anchors) - 1)
    left_anchor, right_anchor = anchors[right - 1], anchors[right]
    alpha = (value - left_anchor) / (right_anchor - left_anchor)
    out = value.new_zeros(len(value), len(anchors))
    rows = torch.arange(len(value), device=value.device)
    out[rows, right - 1] = 1.0 - alpha
    out[rows, right] = alpha
    return out


def phenotype_coefficients(data: AnnyData, shape: Tensor, names: tuple[str, ...]) -> Tensor:
    """The blendshape coefficients (B, K) of the phenotypes `shape` (B, len(names)) (the module
    docstring's rule; the phenotypes not named at 0.5), through the projection where Anny compacts
    the blendshapes; in shape's dtype and on its device."""
    batch = shape.shape[0]

    def value(name: str) -> Tensor:
        return shape[:, names.index(name)] if name in names else shape.new_full((batch,), 0.5)

    columns = []
    for name, count in data.variations:
        if name == "race":  # not interpolated: shares of the three race values
            races = ("african", "asian", "caucasian")
            values = torch.stack([value(r) for r in races], dim=1)
            columns.append(values / values.sum(dim=1, keepdim=True))
        else:
            first, last = data.anchors[name]
            anchors = torch.linspace(first, last, count, dtype=shape.dtype, device=shape.device)
            columns.append(_split_weights(value(name), anchors))
    weights = torch.cat(columns, dim=1)  # (B, C)
    mask = data.mask.to(device=shape.device, dtype=shape.dtype).unsqueeze(0)
    coefficients = torch.prod(weights.unsqueeze(1) * mask + (1 - mask), dim=-1)
    return coefficients if data.projection is None else coefficients @ data.projection.to(shape)
