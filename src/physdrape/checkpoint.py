"""Checkpoints: safetensors tensors + JSON, written atomically; nothing is ever unpickled.

A checkpoint is a directory `step-XXXXXXXX/` holding
- `model.safetensors`: the model's parameters and buffers (normaliser statistics included),
- `config.json`: the resolved run configuration (enough to rebuild the model),
- `train_state.safetensors` + `train_state.json` (optional): optimiser moments, RNG states, step.
It is written under a temporary name and renamed into place, and `latest` (a one-line text file
naming the newest checkpoint) is replaced atomically after it, so a crash never leaves a
half-written checkpoint behind a `latest` pointer.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from physdrape.atomic import atomic_directory, write_text

LATEST = "latest"


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read; the message says which file and what to do."""


def optimizer_to_tensors(optimizer: torch.optim.Optimizer) -> tuple[dict[str, torch.Tensor], dict]:
    """Split an optimiser state dict into named tensors and a JSON-able remainder."""
    state = optimizer.state_dict()
    tensors: dict[str, torch.Tensor] = {}
    per_param: dict[str, dict] = {}
    for index, values in state["state"].items():
        plain = {}
        for key, value in values.items():
            if isinstance(value, torch.Tensor):
                tensors[f"optim.{index}.{key}"] = value.detach().contiguous().clone()
            else:
                plain[key] = value
        per_param[str(index)] = plain
    return tensors, {"param_groups": state["param_groups"], "plain_state": per_param}


def optimizer_from_tensors(tensors: dict[str, torch.Tensor], meta: dict) -> dict:
    """Rebuild an optimiser state dict from `optimizer_to_tensors` output."""
    state: dict[int, dict] = {}
    for name, value in tensors.items():
        if name.startswith("optim."):
            _, index, key = name.split(".", 2)
            state.setdefault(int(index), {})[key] = value
    for index, plain in meta["plain_state"].items():
        state.setdefault(int(index), {}).update(plain)
    return {"state": state, "param_groups": meta["param_groups"]}


def save_checkpoint(
    run_dir: str | os.PathLike,
    step: int,
    model: torch.nn.Module,
    config: dict,
    *,
    train_tensors: dict[str, torch.Tensor] | None = None,
    train_meta: dict | None = None,
    keep: int = 3,
) -> Path:
    """Write checkpoint `step` under run_dir atomically and point `latest` at it; keep the newest `keep`."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    final = run_dir / f"step-{step:08d}"
    with atomic_directory(final) as tmp:
        weights = {k: v.detach().contiguous().clone() for k, v in model.state_dict().items()}
        save_file(weights, tmp / "model.safetensors")
        (tmp / "config.json").write_text(json.dumps(config, indent=2, sort_keys=True))
        if train_tensors is not None:
            save_file(train_tensors, tmp / "train_state.safetensors")
            (tmp / "train_state.json").write_text(json.dumps(train_meta or {}, indent=2, sort_keys=True))
    write_text(run_dir / LATEST, final.name + "\n")
    old = sorted(p for p in run_dir.glob("step-*") if p.is_dir())[:-keep] if keep > 0 else []
    for path in old:
        shutil.rmtree(path, ignore_errors=True)
    return final


def latest_checkpoint(run_dir: str | os.PathLike) -> Path | None:
    """The checkpoint `latest` names in run_dir, or None if the run has none yet."""
    pointer = Path(run_dir) / LATEST
    if not pointer.is_file():
        return None
    path = Path(run_dir) / pointer.read_text().strip()
    if not (path / "model.safetensors").is_file():
        raise CheckpointError(f"{pointer} names {path}, which has no model.safetensors; delete {pointer} to start over")
    return path


def read_checkpoint(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict]:
    """(model tensors, config) of a checkpoint directory (or of run_dir's latest)."""
    path = Path(path)
    if (path / LATEST).is_file():
        path = latest_checkpoint(path)
    weights, config = path / "model.safetensors", path / "config.json"
    for needed in (weights, config):
        if not needed.is_file():
            raise CheckpointError(f"{needed} is missing: a PhysDrape checkpoint is a directory with model.safetensors and config.json")
    try:
        return load_file(weights), json.loads(config.read_text())
    except Exception as exc:
        raise CheckpointError(f"cannot read checkpoint {path}: {exc}") from exc


def read_train_state(path: Path) -> tuple[dict[str, torch.Tensor], dict]:
    """(tensors, meta) of a checkpoint's training state."""
    tensors, meta = path / "train_state.safetensors", path / "train_state.json"
    if not tensors.is_file() or not meta.is_file():
        raise CheckpointError(f"{path} has no training state (train_state.*): it cannot be resumed, only loaded")
    return load_file(tensors), json.loads(meta.read_text())


def export_model(checkpoint: str | os.PathLike, out_dir: str | os.PathLike) -> Path:
    """Copy a checkpoint's model (model.safetensors + config.json, no training state) to out_dir,
    atomically: the form in which a trained model is shipped and loaded for inference."""
    source = Path(checkpoint)
    if (source / LATEST).is_file():
        source = latest_checkpoint(source)
    weights, config = read_checkpoint(source)  # validates that both files are readable
    with atomic_directory(out_dir) as tmp:
        shutil.copy2(source / "model.safetensors", tmp / "model.safetensors")
        (tmp / "config.json").write_text(json.dumps({**config, "exported_from": source.name}, indent=2, sort_keys=True))
        for path in (tmp / "model.safetensors", tmp / "config.json"):
            path.chmod(0o644)  # shipped inside the package: readable by everyone
    return Path(out_dir)
