"""The network's inputs at each training instance's X_init, computed once and held.

The network's node inputs at X_init (its features there and, with `ModelConfig.step_inputs`, the
two-level solver's first step there: `PhysDrape.node_inputs`) depend on the instance's X_init,
garment, body and material alone, none of which a cached training instance ever changes. Made at
every step they cost a body query, the stiffness blocks and a coarse space built and factorised
per garment, about a quarter of a training step. `NodeInputsMemo` computes each instance's on its
first use and hands them to the model with the batch (`DrapeInput.x_init_nodes`); the model
computes the inputs of any other positions (a later pass's) itself.
"""

from __future__ import annotations

from dataclasses import replace

from torch import Tensor

from physdrape.train.data import TrainingBatch, held_per_instance

__all__ = ["NodeInputsMemo"]


class NodeInputsMemo:
    """Each cached instance's node inputs at its X_init under `model` (a `PhysDrape`), held by
    instance index (`TrainingBatch.instances`)."""

    def __init__(self, model) -> None:
        self.model = model
        self._held: dict[int, Tensor] = {}

    def attach(self, sample: TrainingBatch) -> TrainingBatch:
        """The sample with its instances' node inputs in its `DrapeInput.x_init_nodes` (those not
        held yet computed on its whole batch first); a sample drawn without a cache unchanged."""
        if sample.instances is None:
            return sample
        nodes = held_per_instance(self._held, sample, lambda: self.model.node_inputs(sample.drape))
        return replace(sample, drape=replace(sample.drape, x_init_nodes=nodes))
