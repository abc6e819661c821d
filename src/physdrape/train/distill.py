"""The network's own passes as its teacher: self-distillation of several passes into one.

Run as k passes, one set of weights drapes much closer to equilibrium than as one pass (each pass
reads the forces and the solver's step where the passes before it left the garment,
`ModelConfig.passes`), but every pass costs a network evaluation and its inputs. `PassesTeacher`
holds a frozen copy of the network a fine-tune starts from (`OptimConfig.init_from`), run as
`LossConfig.distill_passes` passes without the solver, and gives each training sample its drape
X_init + Δx₁ + … + Δx_k; the loss pulls the one-pass drape toward it (`LossConfig.distill_weight`)
beside the energy. The target is made by physics alone: the teacher is the network the energy
loss trained, so no data beyond the training instances enters.

Unlike the solver's converged drape (`LossConfig.teacher_weight`), whose garment-wide slide a
network pass cannot make, the teacher's drape is one the network already makes, in k steps: the
pull asks one pass for what the same weights reach in k, a per-vertex target where the energy's
gradient is dominated by the stiff strain modes.

The teacher is deterministic per cached instance (its weights are frozen, the instance's X_init,
body and material fixed), so each instance's drape is computed once, on first use, and held.
"""

from __future__ import annotations

import os
from dataclasses import replace

import torch
from torch import Tensor

from physdrape.model.config import Variant
from physdrape.train.data import TrainingBatch, held_per_instance

__all__ = ["PassesTeacher"]


class PassesTeacher:
    """The network of `checkpoint` (a checkpoint or run directory) as `passes` passes without the
    solver, frozen, on `device`; `drapes(sample)` gives the sample's teacher drape (ΣV, 3) [m]."""

    def __init__(self, checkpoint: str | os.PathLike, passes: int, device: torch.device) -> None:
        from physdrape.checkpoint import load_model

        if passes < 2:
            raise ValueError(f"the teacher's passes must be ≥ 2 (one pass is the network itself), got {passes}")
        self.model, _ = load_model(checkpoint, variant=Variant.GNN_ONLY, passes=passes)
        self.model.to(device).eval()
        for parameter in self.model.parameters():
            parameter.requires_grad_(False)
        self._held: dict[int, Tensor] = {}

    @torch.no_grad()
    def drapes(self, sample: TrainingBatch) -> Tensor:
        """The teacher's drape of each garment of the sample, packed as its vertices (ΣV, 3) [m],
        in the sample's dtype; held per cached instance (`TrainingBatch.instances`), recomputed
        for samples drawn without a cache. The teacher makes its own inputs: node inputs the
        batch holds are the trained network's (`DrapeInput.x_init_nodes`), not necessarily its."""
        batch = replace(sample.drape, x_init_nodes=None)
        if sample.instances is None:
            return self._run(batch)
        return held_per_instance(self._held, sample, lambda: self._run(batch))

    def _run(self, batch) -> Tensor:
        return self.model(batch).x_gnn.to(batch.x_init.dtype)
