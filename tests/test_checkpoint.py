"""Checkpoints: one loader for everyone, run directories resolved by `latest`, and errors that
name the file, what is wrong with it and what to do."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

from physdrape import checkpoint as ckpt
from physdrape.model import Variant


@pytest.fixture
def model_dir(tiny_checkpoint, tmp_path) -> Path:
    """A copy of the tiny test checkpoint that a test may damage."""
    return Path(shutil.copytree(tiny_checkpoint, tmp_path / "model"))


def test_load_model_from_a_checkpoint_and_from_its_run_directory(tiny_checkpoint):
    model, info = ckpt.load_model(tiny_checkpoint)
    assert not model.training and info["step"] == 0 and info["variant"] == "full"
    same, info_run = ckpt.load_model(Path(tiny_checkpoint).parent)  # a run directory: its latest
    assert info_run["path"] == info["path"]
    for (name, a), (_, b) in zip(model.state_dict().items(), same.state_dict().items()):
        assert torch.equal(a, b), name
    gnn, info_gnn = ckpt.load_model(tiny_checkpoint, variant=Variant.GNN_ONLY)
    assert gnn.config.variant is Variant.GNN_ONLY and info_gnn["variant"] == "gnn"


def test_a_damaged_weights_file_is_named_with_the_fix(model_dir):
    (model_dir / "model.safetensors").write_bytes(b"\x00\x01 not a safetensors file")
    with pytest.raises(ckpt.CheckpointError) as err:
        ckpt.load_model(model_dir)
    message = str(err.value)
    assert str(model_dir / "model.safetensors") in message and "damaged" in message and "re-export" in message


@pytest.mark.parametrize("damage, pattern", [
    (lambda d: (d / "config.json").write_text("{not json"), "config.json is not valid JSON"),
    (lambda d: (d / "config.json").unlink(), "config.json is missing"),
    (lambda d: (d / "config.json").write_text(json.dumps({"train": {}})), "no train.model section"),
    (lambda d: (d / "config.json").write_text(json.dumps({"train": {"model": {"latent": 8, "wings": 2}}})),
     r"unknown keys \['wings'\]"),
    (lambda d: (d / "config.json").write_text(json.dumps({"train": {"model": {"latent": 9, "blocks": 1}}})),
     "does not match its config.json"),
])
def test_a_bad_config_is_named_with_the_fix(model_dir, damage, pattern):
    damage(model_dir)
    with pytest.raises(ckpt.CheckpointError, match=pattern):
        ckpt.load_model(model_dir)


def test_missing_paths_say_what_a_checkpoint_is(tmp_path):
    with pytest.raises(ckpt.CheckpointError, match="does not exist.*physdrape train"):
        ckpt.resolve(tmp_path / "nowhere")
    (tmp_path / "file").write_text("x")
    with pytest.raises(ckpt.CheckpointError, match="is a file"):
        ckpt.resolve(tmp_path / "file")


def test_the_api_reports_a_damaged_checkpoint_in_one_plain_message(model_dir):
    from physdrape.api import DrapeError, Draper

    (model_dir / "model.safetensors").write_bytes(b"garbage")
    with pytest.raises(DrapeError) as err:
        Draper(model_dir)
    assert "model.safetensors" in str(err.value)
    assert err.value.__cause__ is None and err.value.__suppress_context__  # no chained traceback


def test_the_bundled_model_loads():
    model, info = ckpt.load_model(ckpt.bundled_model())
    assert info["variant"] == "full" and model.config.solver.value == "two_level"
