"""The held-out validation set of a run config, for benchmarks that drape it with a checkpoint.

`physdrape.train.validation` describes the set: garments and bodies never trained on, each with
its teacher drape (the two-level solver run to near convergence from the same X_init).
"""

from __future__ import annotations

from dataclasses import replace

import torch

from physdrape.checkpoint import load_model
from physdrape.config_io import load_config
from physdrape.model import PhysDrape, Variant
from physdrape.physics.energy import drape_energies
from physdrape.train.data import DrapeSource
from physdrape.train.trainer import TrainConfig


def full_model(checkpoint: str, **override) -> PhysDrape:
    """The checkpoint's weights in the full variant (GNN → solver → handler), with `override`
    fields of its `ModelConfig`, in eval mode."""
    trained, _ = load_model(checkpoint)
    model = PhysDrape(replace(trained.config, variant=Variant.FULL, **override)).eval()
    model.load_state_dict(trained.state_dict())
    return model


def validation_batches(config: str) -> list:
    """The validation instances of `config`'s data section (one batch each, with its teacher)."""
    train_config = load_config(TrainConfig, config)
    batches = DrapeSource(train_config.data, model=train_config.model).validation()
    if not batches:
        raise SystemExit(f"{config}: its data section has no instance cache, so no validation set")
    return batches


def energies(x: torch.Tensor, drape, model: PhysDrape) -> tuple[float, float]:
    """(E_total, E_strain) [J] of one drape x of batch `drape`, with the model's contact term."""
    terms = drape_energies(x, drape.cloth, drape.bodies, drape.body_index,
                           contact_stiffness=model.config.contact_stiffness, margin=model.config.margin)
    return float(sum(terms.values())[0]), float(terms["strain"][0])
