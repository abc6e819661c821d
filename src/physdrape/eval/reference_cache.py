"""A folder of the oracle's results from the skinned start, one entry per instance.

That oracle run does not involve the model, so its result serves every checkpoint evaluated on
the same instance: a re-run with another checkpoint only runs the model rows and the refinement
from the model's drape. An entry is named by a digest (`reference_key`) of everything the result
depends on: the start positions, the garment (rest positions, faces, every per-element
coefficient of its material, its grip, stitches and layer order: the whole `Cloth`), the posed
body (vertices, faces) and the oracle's settings (contact model, stiffness, margin, tolerance,
iteration cap, wall-time budget, dtype; for a garment whose layer pairs the oracle completes as
it goes, how far a vertex moves before it searches them again; for a garment of several pieces,
how the oracle keeps them from crossing), with `CACHE_FORMAT` and the physdrape version. Change
any of them and the entry is missed; `relax`'s code is not in the digest: bump `CACHE_FORMAT`
when its results change.

An entry is two files: ``<key>.safetensors`` (the relaxed positions x [m], (V, 3) float64) and
``<key>.json`` (the record of the run: iterations, converged, reason, residual, wall time,
energies, history; and the sha256 of the positions file). Each is written atomically, the
positions first, so a record always names complete positions. An entry that cannot be read back
whole (bad JSON, wrong key, checksum or shape) is reported with a warning and recomputed.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from dataclasses import fields, is_dataclass
from pathlib import Path

import safetensors.torch
import torch

import physdrape
from physdrape.atomic import write_bytes, write_text
from physdrape.model import DrapeInput
from physdrape.physics.oracle.crossings import PieceGuard
from physdrape.physics.oracle.newton import FOLLOW_MOVE, HOLD_ROUNDS

__all__ = ["CACHE_FORMAT", "ReferenceCache", "reference_key"]

#: Part of every key: bumped whenever the oracle's result for the same inputs changes.
CACHE_FORMAT = "physdrape-eval-reference/1"


def _update(digest, name: str, tensor: torch.Tensor) -> None:
    t = tensor.detach().cpu().contiguous()
    digest.update(f"{name}:{t.dtype}:{tuple(t.shape)};".encode())
    digest.update(t.numpy().tobytes())


def reference_key(batch: DrapeInput, start: torch.Tensor, settings: dict) -> str:
    """The digest naming the oracle's result on `batch` from `start` under `settings` (a
    JSON-ready dict of the oracle's settings): 32 hex digits."""
    digest = hashlib.sha256()
    head = {"format": CACHE_FORMAT, "physdrape": physdrape.__version__, "settings": settings,
            "num_garments": batch.cloth.num_garments}
    layers = batch.cloth.layers
    if layers is not None and layers.follows:  # when the oracle searches the layer pairs again
        head["layer_search_move_m"] = FOLLOW_MOVE
    cloth = batch.cloth
    if PieceGuard.of(cloth.faces, cloth.face_garment, cloth.num_verts, cloth.num_garments) is not None:
        # the line search refuses steps that cross pieces, holding those faces' corners after
        head["piece_guard"] = {"hold_rounds": HOLD_ROUNDS}
    digest.update(json.dumps(head, sort_keys=True).encode())
    tensors = {"start": start, "garment.rest": batch.garments.rest, "garment.faces": batch.garments.faces,
               "body.verts": batch.bodies.verts, "body.faces": batch.bodies.faces, "body_index": batch.body_index}
    for f in fields(batch.cloth):
        value = getattr(batch.cloth, f.name)
        if isinstance(value, torch.Tensor):
            tensors[f"cloth.{f.name}"] = value
        elif is_dataclass(value):  # the grip, stitches and layer order: terms of the energy
            for g in fields(value):
                if isinstance(getattr(value, g.name), torch.Tensor):
                    tensors[f"cloth.{f.name}.{g.name}"] = getattr(value, g.name)
    for name in sorted(tensors):
        _update(digest, name, tensors[name])
    return digest.hexdigest()[:32]


class ReferenceCache:
    """The entries under `root` (created on the first write); `hits` / `misses` count the look-ups."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.hits = 0
        self.misses = 0

    def paths(self, key: str) -> tuple[Path, Path]:
        """(positions file, record file) of entry `key`."""
        return self.root / f"{key}.safetensors", self.root / f"{key}.json"

    def load(self, key: str, num_verts: int) -> tuple[torch.Tensor, dict] | None:
        """(x float64 (num_verts, 3), record) of entry `key`, or None when there is none or it is
        damaged (then with a warning)."""
        x_path, record_path = self.paths(key)
        if not record_path.is_file():  # never written, or stopped between its two files
            self.misses += 1
            return None
        try:
            entry = json.loads(record_path.read_text())
            if entry.get("format") != CACHE_FORMAT or entry.get("key") != key:
                raise ValueError(f"it is of format {entry.get('format')!r}, key {entry.get('key')!r}")
            data = x_path.read_bytes()
            if hashlib.sha256(data).hexdigest() != entry["x_sha256"]:
                raise ValueError(f"{x_path.name} does not match the sha256 its record gives")
            x = safetensors.torch.load(data)["x"]
            if x.dtype != torch.float64 or tuple(x.shape) != (num_verts, 3):
                raise ValueError(f"positions of {x.dtype}, shape {tuple(x.shape)}; expected float64 ({num_verts}, 3)")
            record = dict(entry["record"])
        except Exception as exc:
            warnings.warn(f"reference cache entry {record_path} is damaged ({type(exc).__name__}: {exc}); "
                          "running the oracle again and rewriting it", RuntimeWarning, stacklevel=2)
            self.misses += 1
            return None
        self.hits += 1
        return x, record

    def store(self, key: str, x: torch.Tensor, record: dict) -> None:
        """Write entry `key`: positions `x` [m] (V, 3) as float64 and the JSON-ready `record`.
        A failed write is a warning: the evaluation goes on without the entry."""
        x_path, record_path = self.paths(key)
        data = safetensors.torch.save({"x": x.detach().cpu().to(torch.float64).contiguous()})
        entry = {"format": CACHE_FORMAT, "key": key, "x_sha256": hashlib.sha256(data).hexdigest(), "record": record}
        try:
            write_bytes(x_path, data)
            write_text(record_path, json.dumps(entry, indent=1) + "\n")
        except OSError as exc:
            warnings.warn(f"could not write the reference cache entry {record_path} ({exc}); going on without it",
                          RuntimeWarning, stacklevel=2)
