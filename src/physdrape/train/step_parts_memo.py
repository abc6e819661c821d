"""The solver's first step at each training instance's X_init, computed once and held.

With `ModelConfig.step_inputs` the network reads the two-level solver's first-step parts at its
input positions (`PhysDrape.step_parts_at`). A cached training instance's X_init, body and
material never change, so neither do those parts at X_init: computing them at every step (a body
query, the stiffness blocks, the coarse space built and factorised) costs a fifth of a training
step and would rebuild the coarse space of every garment a step draws. `StepPartsMemo` computes
each instance's parts on its first use and hands them to the model with the batch
(`DrapeInput.step_parts`); the model computes the parts of any other positions itself.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from physdrape.train.data import TrainingBatch

__all__ = ["StepPartsMemo"]


class StepPartsMemo:
    """Each cached instance's first-step parts at its X_init under `model` (a `PhysDrape` whose
    config reads them), held by instance index (`TrainingBatch.instances`)."""

    def __init__(self, model) -> None:
        self.model = model
        self._held: dict[int, tuple[Tensor, ...]] = {}

    def attach(self, sample: TrainingBatch) -> TrainingBatch:
        """The sample with its instances' parts in its `DrapeInput.step_parts` (those not held yet
        computed on its whole batch first); a sample drawn without a cache, or a model that does
        not read the parts, unchanged."""
        if sample.instances is None or not self.model.config.step_inputs:
            return sample
        batch = sample.drape
        if any(k not in self._held for k in sample.instances):
            offsets = batch.garments.vert_offsets.tolist()
            parts = self.model.step_parts_at(batch)
            for g, key in enumerate(sample.instances):
                self._held.setdefault(key, tuple(p[offsets[g]:offsets[g + 1]].clone() for p in parts))
        held = [self._held[key] for key in sample.instances]
        step_parts = tuple(torch.cat([parts[k] for parts in held]) for k in range(len(held[0])))
        return replace(sample, drape=replace(batch, step_parts=step_parts))
