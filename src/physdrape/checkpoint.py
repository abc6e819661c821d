"""Checkpoints: safetensors tensors + JSON, written atomically; nothing is ever unpickled.

A checkpoint is a directory `step-XXXXXXXX/` (or any directory, for an exported model) holding
- `model.safetensors`: the model's parameters and buffers (normaliser statistics included),
- `config.json`: the resolved run configuration (its ``train.model`` section rebuilds the model),
- `train_state.safetensors` + `train_state.json` (optional): optimiser moments, RNG states, step.
A run directory holds several checkpoints and `latest`, a one-line text file naming the newest.
Checkpoints are written under a temporary name and renamed into place, and `latest` is replaced
atomically after it, so a crash never leaves a half-written checkpoint behind a `latest` pointer.

This module is the only place that reads or writes them: the API, training, evaluation and the
CLI load models with `load_model` and resolve run directories with `resolve`.
"""

from __future__ import annotations

import json
import os
import shutil
from dataclasses import replace
from importlib.resources import files
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from physdrape.atomic import atomic_directory, write_text
from physdrape.config_io import ConfigError, from_mapping
from physdrape.model import ModelConfig, PhysDrape, Variant

LATEST = "latest"
MODEL_FILE = "model.safetensors"
CONFIG_FILE = "config.json"


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read; the message says which file and what to do."""


def bundled_model() -> Path:
    """Where the bundled model lives: ``physdrape/assets/models/cpu_default``."""
    return Path(str(files("physdrape") / "assets" / "models" / "cpu_default"))


def resolve(path: str | os.PathLike) -> Path:
    """The checkpoint directory `path` names: itself, or for a run directory the checkpoint its
    `latest` file points at. CheckpointError (naming the file and the fix) when there is none."""
    path = Path(path).expanduser()
    if not path.exists():
        raise CheckpointError(
            f"{path} does not exist: give a checkpoint directory (model.safetensors + config.json) or a training "
            "run directory (with a `latest` file); train one with `physdrape train --config CONFIG --run-dir DIR`")
    if not path.is_dir():
        raise CheckpointError(f"{path} is a file: give the checkpoint directory that holds {MODEL_FILE} and "
                              f"{CONFIG_FILE} (or a run directory)")
    if (path / LATEST).is_file():
        latest = latest_checkpoint(path)
        assert latest is not None
        return latest
    return path


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
    """(model tensors, config) of a checkpoint directory (or of a run directory's latest)."""
    path = resolve(path)
    weights, config = path / MODEL_FILE, path / CONFIG_FILE
    for needed in (weights, config):
        if not needed.is_file():
            raise CheckpointError(f"{needed} is missing: a PhysDrape checkpoint is a directory with {MODEL_FILE} and "
                                  f"{CONFIG_FILE}; {_FIX}")
    try:
        tensors = load_file(weights)
    except Exception as exc:  # safetensors raises its own error types on damaged files
        raise CheckpointError(f"{weights} is damaged or not a safetensors file ({exc}); {_FIX}") from None
    try:
        return tensors, json.loads(config.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CheckpointError(f"{config} is not valid JSON ({exc}); {_FIX}") from None


#: What to do about a checkpoint that cannot be read.
_FIX = ("point to another checkpoint, re-export it from its run directory (python -m physdrape.train.ship), or for "
        "the bundled model reinstall PhysDrape (pip install -e .)")


def load_model(path: str | os.PathLike, *, variant: Variant | None = None,
               passes: int | None = None) -> tuple[PhysDrape, dict]:
    """The model of a checkpoint (directory, or a run directory: its latest), in eval mode, its
    network in the dtype it was trained in, switched to `variant` when given, else to the variant
    the checkpoint was exported to run as (config.json's "variant", `export_model`), else the one
    it was trained as; its network run as `passes` passes when given, else as many as it was
    exported to run (config.json's "passes"), else as many as it was trained with; its solver
    started from the network's move extrapolated by the gain it was exported with (config.json's
    "eval_move_gain", `ModelConfig.eval_move_gain`), else as trained.

    Returns (model, info {"path", "step", "variant", "passes", "eval_steps", "dtype"}).
    """
    path = resolve(path)
    tensors, config = read_checkpoint(path)
    train = config.get("train") if isinstance(config.get("train"), dict) else {}
    if "model" not in train:
        raise CheckpointError(f"{path / CONFIG_FILE} has no train.model section: not a PhysDrape checkpoint; {_FIX}")
    try:
        model_cfg = from_mapping(ModelConfig, train["model"], where=f"{path / CONFIG_FILE}:train.model")
    except ConfigError as exc:
        raise CheckpointError(f"{exc}; the checkpoint was written by another PhysDrape version or edited: {_FIX}") from None
    if variant is None and config.get("variant") is not None:
        try:
            variant = Variant(config["variant"])
        except ValueError:
            raise CheckpointError(f"{path / CONFIG_FILE}: variant {config['variant']!r} is not one of "
                                  f"{[v.value for v in Variant]}; {_FIX}") from None
    if variant is not None:
        model_cfg = replace(model_cfg, variant=variant)
    if passes is not None and (not isinstance(passes, int) or isinstance(passes, bool) or passes < 1):
        raise CheckpointError(f"passes must be an integer ≥ 1 (network passes before the solver), got {passes!r}")
    if passes is None and config.get("passes") is not None:
        passes = config["passes"]
        if not isinstance(passes, int) or passes < 1:
            raise CheckpointError(f"{path / CONFIG_FILE}: passes {passes!r} is not an integer ≥ 1; {_FIX}")
    if passes is not None:
        model_cfg = replace(model_cfg, passes=passes)
    gain = config.get("eval_move_gain")
    if gain is not None:
        if isinstance(gain, bool) or not isinstance(gain, (int, float)) or not gain > 0:
            raise CheckpointError(f"{path / CONFIG_FILE}: eval_move_gain {gain!r} is not a number > 0; {_FIX}")
        model_cfg = replace(model_cfg, eval_move_gain=float(gain))
    dtype = getattr(torch, str(train.get("dtype", "float32")), None)
    if dtype not in (torch.float32, torch.float64):
        raise CheckpointError(f"{path / CONFIG_FILE}: train.dtype {train.get('dtype')!r} is not float32 or float64")
    model = PhysDrape(model_cfg).to(dtype)
    try:
        model.load_state_dict(tensors)
    except RuntimeError as exc:
        raise CheckpointError(f"{path / MODEL_FILE} does not match its {CONFIG_FILE} ({exc}); {_FIX}") from None
    model.eval()
    step = path.name.split("-")[-1]
    info = {"path": str(path.resolve()), "step": int(step) if step.isdigit() else None,
            "variant": model_cfg.variant.value, "passes": model_cfg.passes, "eval_steps": model_cfg.eval_steps,
            "dtype": str(dtype).removeprefix("torch.")}
    return model, info


def read_train_state(path: Path) -> tuple[dict[str, torch.Tensor], dict]:
    """(tensors, meta) of a checkpoint's training state."""
    tensors, meta = path / "train_state.safetensors", path / "train_state.json"
    if not tensors.is_file() or not meta.is_file():
        raise CheckpointError(f"{path} has no training state (train_state.*): it cannot be resumed, only loaded")
    return load_file(tensors), json.loads(meta.read_text())


def export_model(checkpoint: str | os.PathLike, out_dir: str | os.PathLike, *,
                 variant: Variant | str | None = None, passes: int | None = None,
                 eval_move_gain: float | None = None) -> Path:
    """Copy a checkpoint's model (model.safetensors + config.json, no training state) to out_dir,
    atomically: the form in which a trained model is shipped and loaded for inference.

    variant: the variant the exported model runs as (`load_model`'s default), e.g. "full" for a
    network trained alone (GNN-only) that is to drape through the solver and the handler; the
    config's train section keeps the variant it was trained as. None: as trained.
    passes: the network passes the exported model makes (`load_model`'s default; `ModelConfig.passes`),
    e.g. 2 for a network trained as one pass that is to look again at the garment it moved. None:
    as trained.
    eval_move_gain: the gain g of the exported model's solver start X_init + g Δx
    (`ModelConfig.eval_move_gain`). None: as trained."""
    if passes is not None and (not isinstance(passes, int) or passes < 1):
        raise ValueError(f"passes must be an integer ≥ 1, got {passes!r}")
    if eval_move_gain is not None and not eval_move_gain > 0:
        raise ValueError(f"eval_move_gain must be > 0, got {eval_move_gain!r}")
    source = resolve(checkpoint)
    _, config = read_checkpoint(source)  # validates that both files are readable
    extra = {"exported_from": source.name}
    if variant is not None:
        extra["variant"] = Variant(variant).value
    if passes is not None:
        extra["passes"] = passes
    if eval_move_gain is not None:
        extra["eval_move_gain"] = float(eval_move_gain)
    with atomic_directory(out_dir) as tmp:
        shutil.copy2(source / "model.safetensors", tmp / "model.safetensors")
        (tmp / "config.json").write_text(json.dumps({**config, **extra}, indent=2, sort_keys=True))
        for path in (tmp / "model.safetensors", tmp / "config.json"):
            path.chmod(0o644)  # shipped inside the package: readable by everyone
    return Path(out_dir)
